//! The live subcommands: the daemon and what talks to it over iceoryx2
//! (`serve`, `sim`, `demo`, `bench-ipc`).

pub mod bench_ipc;
pub mod daemon_args;
pub mod demo;
pub mod faults;
pub mod serve;
pub mod sim;
