//! All integration tests in one binary (each tests/*.rs file would be its own large binary).

mod cli;
mod common;
mod comp;
mod diagnose;
mod evidence;
mod export;
mod fuzz_regressions;
mod indep;
mod kill;
mod layers;
mod limits;
mod linuxcnc;
mod nc;
mod physics;
mod presets;
mod self_replay;
mod stability;
mod trace_io;
mod tune;
