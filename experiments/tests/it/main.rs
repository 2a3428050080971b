//! Integration tests of the experiments, each on a tiny configuration: every figure of every
//! experiment, the robot and transfer experiments end to end, and sharding, merging and
//! resuming.

mod drawing;
mod figures;
mod robot;
mod shards;
mod transfer;
