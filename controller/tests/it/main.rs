//! Integration tests of the controller: the acting loop driven over the paper's arena Env 3
//! (deciding first makes the decisions learning first made). The proof that the acting loop
//! allocates nothing is a binary of its own (`allocations.rs`): it installs a counting global
//! allocator.

mod decide_first;
mod driver;
