//! The flowopt planning daemon; built in issue 3.
