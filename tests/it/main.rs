//! All integration tests in one binary (each tests/*.rs file would be its own large binary).

mod cli;
mod common;
mod comp;
mod diagnose;
mod export;
mod linuxcnc;
mod nc;
mod physics;
mod presets;
mod trace_io;
