//! `tes launch --ros2` and `--rosbag` (docs/ros2.md): a `tes` built without the `ros2`
//! feature refuses them before anything starts. (The ROS 2 side itself is tested against
//! Cyclone DDS and rosbags in `ros2/tests/it`.)

/// A `tes` without the feature says how to build it in, and starts nothing: no process, no
/// bag directory.
#[cfg(not(feature = "ros2"))]
#[test]
fn ros2_is_refused_by_a_tes_built_without_it() {
    use crate::common::{Group, launch_file};
    use std::time::Duration;

    let dir = tempfile::tempdir().expect("temp dir");
    let bag = dir.path().join("bag");
    let bag_arg = bag.display().to_string();
    for args in [vec!["--ros2"], vec!["--rosbag", bag_arg.as_str()]] {
        let toml = launch_file(dir.path(), "");
        let mut group = Group::start_in(dir.path(), &toml, 1, &args, &[]);
        let (ok, _, stderr) = group.finish(Duration::from_secs(120));
        assert!(!ok, "{args:?} was accepted: {stderr:?}");
        let said = stderr.join("\n");
        assert!(
            said.contains("built without ROS 2")
                && said.contains("--features ros2")
                && said.contains("nothing was started"),
            "{said}"
        );
        assert!(!said.contains("started controller"), "{said}");
        assert!(!bag.exists());
    }
}
