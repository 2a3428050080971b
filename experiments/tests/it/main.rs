//! Integration tests of the experiments, each on a tiny configuration: every figure of every
//! experiment, each experiment end to end, sharding, merging and resuming, and the generated
//! tables of the docs against their result folders.

mod docs;
mod drawing;
mod fig4;
mod figures;
mod lifelong;
mod robot;
mod settings;
mod shards;
mod transfer;
