//! The group's ROS 2 side against independent ROS 2 peers: Eclipse Cyclone DDS (PyPI
//! `cyclonedds`) subscribing with ROS 2's names and types, and PyPI `rosbags` reading the bag.

mod common;
mod publish;
