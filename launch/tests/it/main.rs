//! The launch library's integration tests: the supervisor driven with a fake child program.

mod supervisor;
