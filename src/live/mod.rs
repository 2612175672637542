//! The live subcommands: the daemon and what talks to it over iceoryx2
//! (`serve`, `sim`, `demo`, `bench-ipc`, `ros2`), and what records and shows their
//! traffic (`observe`).

pub mod bench_ipc;
pub mod daemon_args;
pub mod demo;
pub mod faults;
pub mod observe;
pub mod ros2;
pub mod serve;
pub mod sim;
