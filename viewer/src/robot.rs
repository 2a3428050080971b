//! The robot: where it is (the camera's pose at each observation, dead-reckoned from the
//! wheels while it moves) and how it is drawn (a body and a heading arrow, locked to frame
//! [`ROBOT_FRAME`]).

use foxglove::messages::{
    ArrowPrimitive, Color, CubePrimitive, FrameTransform, Pose, Quaternion, SceneEntity, Timestamp,
    Vector3,
};
use tes_perception_sim::arena::{self, DVec2};

use crate::arena::{ARENA_FRAME, M_PER_CM, at, rgb};

/// The robot's own frame: x ahead, y to its left, z up, at the point between its wheels.
/// Where the world knows the robot (the simulated arena, a grid), its true pose.
pub const ROBOT_FRAME: &str = "robot";

/// What the controller believes of the robot: the pose its last observation said (the
/// observed cell's centre and orientation), dead-reckoned from the wheels in between.
pub const BELIEF_FRAME: &str = "belief";

/// Wheel reports kept for drawing the world's motion: far more than one motion brings.
const REPORTS_KEPT: usize = 512;

/// The robot's body, m: length, width, height (an NXT on two wheels).
const BODY_M: [f64; 3] = [0.16, 0.14, 0.10];

/// A pose on the floor: position in cm, heading in radians counter-clockwise from east.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorPose {
    /// Position, cm from the arena's south-west corner.
    pub position: DVec2,
    /// Heading, rad.
    pub heading: f64,
}

impl FloorPose {
    /// The quaternion turning x onto the heading about z.
    pub fn rotation(&self) -> Quaternion {
        let half = self.heading / 2.0;
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: half.sin(),
            w: half.cos(),
        }
    }

    /// As a Foxglove pose, m.
    pub fn pose(&self) -> Pose {
        let mut p = at(self.position.x * M_PER_CM, self.position.y * M_PER_CM, 0.0);
        p.orientation = Some(self.rotation());
        p
    }

    /// The transform `arena → robot` at this pose.
    pub fn transform(&self, timestamp: Timestamp) -> FrameTransform {
        self.transform_of(ROBOT_FRAME, timestamp)
    }

    /// The transform `arena → frame` at this pose.
    pub fn transform_of(&self, frame: &str, timestamp: Timestamp) -> FrameTransform {
        FrameTransform {
            timestamp: Some(timestamp),
            parent_frame_id: ARENA_FRAME.into(),
            child_frame_id: frame.into(),
            translation: Some(Vector3 {
                x: self.position.x * M_PER_CM,
                y: self.position.y * M_PER_CM,
                z: 0.0,
            }),
            rotation: Some(self.rotation()),
        }
    }
}

/// Dead reckoning between observations: each wheel report moves the pose by the ideal
/// differential-drive arc of the wheels' rotation since the last one (no slip: the real motion
/// is only known at the next observation).
#[derive(Debug, Clone, Default)]
pub struct Odometry {
    pose: Option<FloorPose>,
    wheels: Option<[i32; 2]>,
}

impl Odometry {
    /// The pose, once an observation has set one.
    pub fn pose(&self) -> Option<FloorPose> {
        self.pose
    }

    /// Sets the pose the camera saw (`None`: the robot is out of the area, not drawn).
    pub fn observed(&mut self, pose: Option<FloorPose>) {
        self.pose = pose;
    }

    /// Takes the wheels' tacho counts (degrees, left and right) as the baseline of the next
    /// motion, without moving the pose: a report from before the last observation, whose
    /// motion that observation's pose already holds.
    pub fn rebase(&mut self, tacho: [i32; 2]) {
        self.wheels = Some(tacho);
    }

    /// Takes the wheels' tacho counts (degrees, left and right); returns the new pose if the
    /// wheels moved.
    pub fn wheels(&mut self, tacho: [i32; 2]) -> Option<FloorPose> {
        let before = self.wheels.replace(tacho)?;
        let (dl, dr) = (tacho[0] - before[0], tacho[1] - before[1]);
        if dl == 0 && dr == 0 {
            return None;
        }
        let pose = self.pose.as_mut()?;
        let cm_per_deg = std::f64::consts::PI * arena::WHEEL_DIAMETER_CM / 360.0;
        let (left, right) = (f64::from(dl) * cm_per_deg, f64::from(dr) * cm_per_deg);
        let turn = (right - left) / arena::TRACK_WIDTH_CM;
        let mid = pose.heading + turn / 2.0;
        let ahead = (left + right) / 2.0;
        pose.position += DVec2::new(mid.cos(), mid.sin()) * ahead;
        pose.heading = (pose.heading + turn).rem_euclid(std::f64::consts::TAU);
        Some(*pose)
    }
}

/// The world's motion of the robot, drawn continuously: the world says where a motion
/// started and ended (a [`tes_topics::WorldPose`], after the motion); the wheels' reports
/// during it say how far along it the robot was at each report, by the share of the wheels'
/// rotation done. The robot is drawn along the way at each report's time, so it moves as far
/// as its wheels turned, never jumping.
#[derive(Debug, Default)]
pub struct WorldMotion {
    /// Recent wheel reports: time (ns), the command they follow, tacho counts (left, right).
    reports: std::collections::VecDeque<(u64, u64, [i32; 2])>,
}

impl WorldMotion {
    /// Takes a wheel report at `stamp_ns` following command `after_command`.
    pub fn report(&mut self, stamp_ns: u64, after_command: u64, tacho: [i32; 2]) {
        if self.reports.len() == REPORTS_KEPT {
            self.reports.pop_front();
        }
        self.reports.push_back((stamp_ns, after_command, tacho));
    }

    /// The poses of the motion of command `after_command` from `from` to `to`, at the times
    /// of its wheel reports up to `until_ns`, ending at `to`; forgets the reports of earlier
    /// commands. An episode's start (`after_command` 0) is `to` alone.
    pub fn along(
        &mut self,
        after_command: u64,
        from: FloorPose,
        to: FloorPose,
        until_ns: u64,
    ) -> Vec<(u64, FloorPose)> {
        let mut poses = Vec::new();
        if after_command != 0 {
            let baseline = self
                .reports
                .iter()
                .rev()
                .find(|r| r.1 < after_command)
                .or_else(|| self.reports.iter().find(|r| r.1 == after_command))
                .map(|r| r.2);
            let during: Vec<(u64, [i32; 2])> = self
                .reports
                .iter()
                .filter(|r| r.1 == after_command && r.0 <= until_ns)
                .map(|r| (r.0, r.2))
                .collect();
            if let Some(base) = baseline {
                let turned =
                    |t: [i32; 2]| f64::from((t[0] - base[0]).abs() + (t[1] - base[1]).abs());
                let total = during.iter().map(|d| turned(d.1)).fold(0.0, f64::max);
                for (stamp, tacho) in during {
                    let share = if total > 0.0 {
                        turned(tacho) / total
                    } else {
                        1.0
                    };
                    poses.push((stamp, from.towards(to, share)));
                }
            }
            self.reports.retain(|r| r.1 >= after_command);
        }
        poses.push((until_ns, to));
        poses
    }
}

impl FloorPose {
    /// The pose `share` (0 to 1) of the way from this one to `to`: the position on the line
    /// between them, the heading turned the short way round.
    pub fn towards(self, to: FloorPose, share: f64) -> FloorPose {
        let share = share.clamp(0.0, 1.0);
        let tau = std::f64::consts::TAU;
        let mut turn = (to.heading - self.heading).rem_euclid(tau);
        if turn > std::f64::consts::PI {
            turn -= tau;
        }
        FloorPose {
            position: self.position.lerp(to.position, share),
            heading: (self.heading + turn * share).rem_euclid(tau),
        }
    }
}

/// What the controller believes of the robot drawn as a faint outline of its body, locked to
/// [`BELIEF_FRAME`].
pub fn belief_body(timestamp: Timestamp) -> SceneEntity {
    let [l, w, h] = BODY_M;
    SceneEntity {
        timestamp: Some(timestamp),
        frame_id: BELIEF_FRAME.into(),
        id: "belief".into(),
        frame_locked: true,
        cubes: vec![CubePrimitive {
            pose: Some(at(0.0, 0.0, h / 2.0)),
            size: Some(Vector3 { x: l, y: w, z: h }),
            color: Some(Color {
                a: 0.3,
                ..rgb(0.35, 0.7, 1.0)
            }),
        }],
        ..SceneEntity::default()
    }
}

/// The robot's body and heading, drawn once and locked to [`ROBOT_FRAME`], `scale` times an
/// NXT's size (1 on the arena).
pub fn body(timestamp: Timestamp, scale: f64) -> SceneEntity {
    let [l, w, h] = BODY_M.map(|d| d * scale);
    let shell = rgb(0.92, 0.55, 0.08);
    SceneEntity {
        timestamp: Some(timestamp),
        frame_id: ROBOT_FRAME.into(),
        id: "robot".into(),
        frame_locked: true,
        cubes: vec![CubePrimitive {
            pose: Some(at(0.0, 0.0, h / 2.0)),
            size: Some(Vector3 { x: l, y: w, z: h }),
            color: Some(Color { a: 0.85, ..shell }),
        }],
        arrows: vec![ArrowPrimitive {
            pose: Some(at(0.0, 0.0, h + 0.01)),
            shaft_length: l * 0.7,
            shaft_diameter: 0.015 * scale,
            head_length: 0.05 * scale,
            head_diameter: 0.04 * scale,
            color: Some(rgb(0.95, 0.95, 0.95)),
        }],
        ..SceneEntity::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_wheel_turns_drive_straight_and_opposite_ones_spin_in_place() {
        let mut odo = Odometry::default();
        odo.observed(Some(FloorPose {
            position: DVec2::new(50.0, 50.0),
            heading: 0.0,
        }));
        assert_eq!(odo.wheels([0, 0]), None, "the first report is the baseline");
        let ahead = odo.wheels([360, 360]).expect("moved");
        let circumference = std::f64::consts::PI * arena::WHEEL_DIAMETER_CM;
        assert!((ahead.position.x - (50.0 + circumference)).abs() < 1e-9);
        assert!(ahead.position.y == 50.0 && ahead.heading == 0.0);
        // Spinning: the left wheel back, the right one forward, a quarter turn left.
        let quarter = arena::TRACK_WIDTH_CM * std::f64::consts::FRAC_PI_4 / circumference * 360.0;
        let q = quarter.round() as i32;
        let spun = odo.wheels([360 - q, 360 + q]).expect("moved");
        assert!((spun.position - ahead.position).length() < 1e-9);
        assert!(
            (spun.heading - std::f64::consts::FRAC_PI_2).abs() < 0.01,
            "{spun:?}"
        );
    }

    #[test]
    fn the_worlds_motion_goes_as_far_as_the_wheels_turned_and_ends_where_the_world_says() {
        let from = FloorPose {
            position: DVec2::new(10.0, 10.0),
            heading: 0.1,
        };
        // The wheels slipped: 20 cm of wheel travel moved the robot 8 cm.
        let to = FloorPose {
            position: DVec2::new(18.0, 10.0),
            heading: std::f64::consts::TAU - 0.1,
        };
        let mut motion = WorldMotion::default();
        motion.report(1, 6, [100, 100]);
        for (i, deg) in [150, 200, 300].into_iter().enumerate() {
            motion.report(10 + i as u64, 7, [deg, deg]);
        }
        motion.report(99, 8, [400, 400]);
        let poses = motion.along(7, from, to, 50);
        let xs: Vec<f64> = poses.iter().map(|(_, p)| p.position.x).collect();
        assert_eq!(xs.len(), 4, "three reports and the end: {poses:?}");
        assert!(
            (xs[0] - 12.0).abs() < 1e-9 && (xs[1] - 14.0).abs() < 1e-9,
            "{xs:?}"
        );
        assert_eq!(poses[3], (50, to));
        // Turned the short way, through 0, not round.
        let h = poses[0].1.heading;
        assert!(!(0.1..=std::f64::consts::TAU - 0.1).contains(&h), "{h}");
        // The next motion's baseline is this one's last report.
        assert_eq!(motion.reports.front().map(|r| r.1), Some(7));
        // An episode's start is its pose alone.
        assert_eq!(motion.along(0, to, from, 60), vec![(60, from)]);
    }

    #[test]
    fn the_transform_turns_the_robot_frame_to_its_heading() {
        let p = FloorPose {
            position: DVec2::new(100.0, 20.0),
            heading: std::f64::consts::PI,
        };
        let t = p.transform(Timestamp::new(0, 0));
        let r = t.rotation.expect("rotated");
        assert!((r.z - 1.0).abs() < 1e-12 && r.w.abs() < 1e-12);
        assert_eq!(t.translation.expect("moved").x, 1.0);
    }
}
