//! Messages and controller API for the flowopt daemon; built in issue 3.
