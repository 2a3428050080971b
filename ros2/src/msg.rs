//! ROS 2's standard messages, as serde structs laid out field for field as their IDL (the
//! layouts of Humble, Jazzy and Kilted, which agree for every type here): serialised to CDR
//! by the DDS layer, or by [`encode`] for a rosbag2 file.
//!
//! Each message type also carries its name (`tf2_msgs/msg/TFMessage`) and its definition in
//! ROS 2's `.msg` syntax with every type it uses appended, as rosbag2 stores it in an MCAP
//! schema (encoding `ros2msg`).

use serde::{Deserialize, Serialize};

/// A ROS 2 message type: its package, name and `.msg` definition.
pub trait Message: Serialize {
    /// Its definition.
    const TYPE: &'static Definition;
}

/// A message type's name and definition, with the types it uses.
#[derive(Debug)]
pub struct Definition {
    /// The package, e.g. `tf2_msgs`.
    pub package: &'static str,
    /// The type's name in its package, e.g. `TFMessage`.
    pub name: &'static str,
    /// Its fields in `.msg` syntax.
    pub text: &'static str,
    /// The types its fields use (not the builtin ones).
    pub uses: &'static [&'static Definition],
}

impl Definition {
    /// The full name, `pkg/msg/Type`, as ROS 2 tools and rosbag2 write it.
    pub fn full_name(&self) -> String {
        format!("{}/msg/{}", self.package, self.name)
    }

    /// The DDS type name, `pkg::msg::dds_::Type_`, as ROS 2's middlewares declare it.
    pub fn dds_name(&self) -> String {
        format!("{}::msg::dds_::{}_", self.package, self.name)
    }

    /// The definition as rosbag2 stores it (`ros2msg`): the type's own fields, then each type
    /// it uses, directly or not, once, under a `MSG: pkg/Type` line.
    pub fn ros2msg(&self) -> String {
        let mut used: Vec<&Definition> = Vec::new();
        self.collect_uses(&mut used);
        let mut text = self.text.to_owned();
        for d in used {
            text.push_str(&"=".repeat(80));
            text.push_str(&format!("\nMSG: {}/{}\n", d.package, d.name));
            text.push_str(d.text);
        }
        text
    }

    fn collect_uses(&self, used: &mut Vec<&'static Definition>) {
        for &d in self.uses {
            if !used.iter().any(|u| std::ptr::eq(*u, d)) {
                used.push(d);
                d.collect_uses(used);
            }
        }
    }
}

/// Why a message could not be encoded.
#[derive(Debug, thiserror::Error)]
#[error("cannot encode a {type_name} as CDR: {reason}")]
pub struct EncodeError {
    type_name: String,
    reason: String,
}

/// `message` as CDR with its 4-byte encapsulation header (little-endian), as a rosbag2 file
/// and the DDS wire carry it.
pub fn encode<M: Message>(message: &M) -> Result<Vec<u8>, EncodeError> {
    cdr::serialize::<_, _, cdr::CdrLe>(message, cdr::Infinite).map_err(|e| EncodeError {
        type_name: M::TYPE.full_name(),
        reason: e.to_string(),
    })
}

macro_rules! definition {
    ($konst:ident, $package:literal, $name:literal, [$($uses:ident),*], $text:literal) => {
        #[doc = concat!("`", $package, "/msg/", $name, "`.")]
        pub static $konst: Definition = Definition {
            package: $package,
            name: $name,
            text: $text,
            uses: &[$(&$uses),*],
        };
    };
}

/// The definitions of the types below.
pub mod defs {
    use super::Definition;

    definition!(
        TIME,
        "builtin_interfaces",
        "Time",
        [],
        "int32 sec\nuint32 nanosec\n"
    );
    definition!(
        DURATION,
        "builtin_interfaces",
        "Duration",
        [],
        "int32 sec\nuint32 nanosec\n"
    );
    definition!(
        HEADER,
        "std_msgs",
        "Header",
        [TIME],
        "builtin_interfaces/Time stamp\nstring frame_id\n"
    );
    definition!(
        VECTOR3,
        "geometry_msgs",
        "Vector3",
        [],
        "float64 x\nfloat64 y\nfloat64 z\n"
    );
    definition!(
        POINT,
        "geometry_msgs",
        "Point",
        [],
        "float64 x\nfloat64 y\nfloat64 z\n"
    );
    definition!(
        QUATERNION,
        "geometry_msgs",
        "Quaternion",
        [],
        "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
    );
    definition!(
        TRANSFORM,
        "geometry_msgs",
        "Transform",
        [VECTOR3, QUATERNION],
        "Vector3 translation\nQuaternion rotation\n"
    );
    definition!(
        TRANSFORM_STAMPED,
        "geometry_msgs",
        "TransformStamped",
        [HEADER, TRANSFORM],
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"
    );
    definition!(
        TF_MESSAGE,
        "tf2_msgs",
        "TFMessage",
        [TRANSFORM_STAMPED],
        "geometry_msgs/TransformStamped[] transforms\n"
    );
    definition!(
        POSE,
        "geometry_msgs",
        "Pose",
        [POINT, QUATERNION],
        "Point position\nQuaternion orientation\n"
    );
    definition!(
        POSE_STAMPED,
        "geometry_msgs",
        "PoseStamped",
        [HEADER, POSE],
        "std_msgs/Header header\nPose pose\n"
    );
    definition!(
        PATH,
        "nav_msgs",
        "Path",
        [HEADER, POSE_STAMPED],
        "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n"
    );
    definition!(
        COLOR_RGBA,
        "std_msgs",
        "ColorRGBA",
        [],
        "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n"
    );
    definition!(
        COMPRESSED_IMAGE,
        "sensor_msgs",
        "CompressedImage",
        [HEADER],
        "std_msgs/Header header\nstring format\nuint8[] data\n"
    );
    definition!(
        UV_COORDINATE,
        "visualization_msgs",
        "UVCoordinate",
        [],
        "float32 u\nfloat32 v\n"
    );
    definition!(
        MESH_FILE,
        "visualization_msgs",
        "MeshFile",
        [],
        "string filename\nuint8[] data\n"
    );
    definition!(
        MARKER,
        "visualization_msgs",
        "Marker",
        [
            HEADER,
            POSE,
            VECTOR3,
            COLOR_RGBA,
            DURATION,
            POINT,
            COMPRESSED_IMAGE,
            UV_COORDINATE,
            MESH_FILE
        ],
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n\
int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\n\
int32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\n\
int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\
std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n\
geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n\
builtin_interfaces/Duration lifetime\nbool frame_locked\ngeometry_msgs/Point[] points\n\
std_msgs/ColorRGBA[] colors\nstring texture_resource\nsensor_msgs/CompressedImage texture\n\
UVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\nMeshFile mesh_file\n\
bool mesh_use_embedded_materials\n"
    );
    definition!(
        MARKER_ARRAY,
        "visualization_msgs",
        "MarkerArray",
        [MARKER],
        "Marker[] markers\n"
    );
    definition!(
        LOG,
        "rcl_interfaces",
        "Log",
        [TIME],
        "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n\
builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\n\
string function\nuint32 line\n"
    );
    definition!(FLOAT64, "std_msgs", "Float64", [], "float64 data\n");
    definition!(UINT32, "std_msgs", "UInt32", [], "uint32 data\n");
    definition!(STRING, "std_msgs", "String", [], "string data\n");
    definition!(
        FLOAT32_MULTI_ARRAY,
        "std_msgs",
        "Float32MultiArray",
        [MULTI_ARRAY_LAYOUT],
        "MultiArrayLayout layout\nfloat32[] data\n"
    );
    definition!(
        FLOAT64_MULTI_ARRAY,
        "std_msgs",
        "Float64MultiArray",
        [MULTI_ARRAY_LAYOUT],
        "MultiArrayLayout layout\nfloat64[] data\n"
    );
    definition!(
        UINT32_MULTI_ARRAY,
        "std_msgs",
        "UInt32MultiArray",
        [MULTI_ARRAY_LAYOUT],
        "MultiArrayLayout layout\nuint32[] data\n"
    );
    definition!(
        MULTI_ARRAY_LAYOUT,
        "std_msgs",
        "MultiArrayLayout",
        [MULTI_ARRAY_DIMENSION],
        "MultiArrayDimension[] dim\nuint32 data_offset\n"
    );
    definition!(
        MULTI_ARRAY_DIMENSION,
        "std_msgs",
        "MultiArrayDimension",
        [],
        "string label\nuint32 size\nuint32 stride\n"
    );
    definition!(
        TWIST,
        "geometry_msgs",
        "Twist",
        [VECTOR3],
        "Vector3 linear\nVector3 angular\n"
    );
}

macro_rules! message {
    ($ty:ident, $def:ident) => {
        impl Message for $ty {
            const TYPE: &'static Definition = &defs::$def;
        }
    };
}

/// `builtin_interfaces/msg/Time`: a wall-clock time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// `ns` nanoseconds since the Unix epoch (saturated to what `sec` holds).
    pub fn from_ns(ns: u64) -> Self {
        Self {
            sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self::about_z(0.0)
    }
}

impl Quaternion {
    /// A rotation by `angle` radians about z (counter-clockwise seen from above).
    pub fn about_z(angle: f64) -> Self {
        let half = angle / 2.0;
        Self {
            x: 0.0,
            y: 0.0,
            z: half.sin(),
            w: half.cos(),
        }
    }
}

/// `geometry_msgs/msg/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation, m.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// When, and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// Parent → child.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`, what `/tf` carries.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}
message!(TfMessage, TF_MESSAGE);

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position, m.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    /// When, and the frame.
    pub header: Header,
    /// The pose.
    pub pose: Pose,
}

/// `nav_msgs/msg/Path`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Path {
    /// When, and the frame.
    pub header: Header,
    /// The poses, in order.
    pub poses: Vec<PoseStamped>,
}
message!(Path, PATH);

/// `std_msgs/msg/ColorRGBA`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRgba {
    /// Red, 0-1.
    pub r: f32,
    /// Green, 0-1.
    pub g: f32,
    /// Blue, 0-1.
    pub b: f32,
    /// Opacity, 0-1.
    pub a: f32,
}

/// `sensor_msgs/msg/CompressedImage` (a marker's texture; unused here, but on the wire).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    /// When, and the frame.
    pub header: Header,
    /// `jpeg` or `png`.
    pub format: String,
    /// The image.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/UVCoordinate`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshFile {
    /// The file's name.
    pub filename: String,
    /// Its bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker`'s shapes used here.
pub mod marker {
    /// One box.
    pub const CUBE: i32 = 1;
    /// One sphere.
    pub const SPHERE: i32 = 2;
    /// Line segments between pairs of `points`.
    pub const LINE_LIST: i32 = 5;
    /// A box at each of `points`, each in its own of `colors`.
    pub const CUBE_LIST: i32 = 6;
    /// A sphere at each of `points`.
    pub const CYLINDER: i32 = 3;
    /// Add or replace.
    pub const ADD: i32 = 0;
}

/// `visualization_msgs/msg/Marker`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// When, and the frame.
    pub header: Header,
    /// Namespace of `id`.
    pub ns: String,
    /// Its id in `ns`.
    pub id: i32,
    /// Its shape ([`marker`]).
    pub r#type: i32,
    /// Add, modify, delete.
    pub action: i32,
    /// Where.
    pub pose: Pose,
    /// Size, m.
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRgba,
    /// How long it stays (0: forever).
    pub lifetime: Duration,
    /// Whether it moves with its frame.
    pub frame_locked: bool,
    /// Points of a list shape.
    pub points: Vec<Point>,
    /// A colour per point.
    pub colors: Vec<ColorRgba>,
    /// A texture's resource.
    pub texture_resource: String,
    /// A texture.
    pub texture: CompressedImage,
    /// Texture coordinates.
    pub uv_coordinates: Vec<UvCoordinate>,
    /// Text of a text marker.
    pub text: String,
    /// A mesh's resource.
    pub mesh_resource: String,
    /// A mesh.
    pub mesh_file: MeshFile,
    /// Whether a mesh brings its own materials.
    pub mesh_use_embedded_materials: bool,
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers.
    pub markers: Vec<Marker>,
}
message!(MarkerArray, MARKER_ARRAY);

/// `rcl_interfaces/msg/Log`, what `/rosout` carries.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Log {
    /// When.
    pub stamp: Time,
    /// Its level ([`log_level`]).
    pub level: u8,
    /// The logger: here the process's role.
    pub name: String,
    /// The line.
    pub msg: String,
    /// Source file (empty here).
    pub file: String,
    /// Function (empty here).
    pub function: String,
    /// Source line (0 here).
    pub line: u32,
}
message!(Log, LOG);

/// `rcl_interfaces/msg/Log`'s levels.
pub mod log_level {
    /// Debug.
    pub const DEBUG: u8 = 10;
    /// Info.
    pub const INFO: u8 = 20;
    /// Warning.
    pub const WARN: u8 = 30;
    /// Error.
    pub const ERROR: u8 = 40;
}

/// `std_msgs/msg/Float64`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64 {
    /// The number.
    pub data: f64,
}
message!(Float64, FLOAT64);

/// `std_msgs/msg/UInt32`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct UInt32 {
    /// The number.
    pub data: u32,
}
message!(UInt32, UINT32);

/// `std_msgs/msg/String`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Text {
    /// The text.
    pub data: String,
}
message!(Text, STRING);

/// `geometry_msgs/msg/Twist`: a base's velocity command.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// m/s.
    pub linear: Vector3,
    /// rad/s.
    pub angular: Vector3,
}
message!(Twist, TWIST);

/// `std_msgs/msg/MultiArrayDimension`: one dimension of a multi-array's layout.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    /// What the dimension counts (`states`, `columns`, `step`).
    pub label: String,
    /// Its size.
    pub size: u32,
    /// Its stride: the elements one step of the dimension above skips.
    pub stride: u32,
}

/// `std_msgs/msg/MultiArrayLayout`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    /// The dimensions, outermost first.
    pub dim: Vec<MultiArrayDimension>,
    /// Elements before the first.
    pub data_offset: u32,
}

impl MultiArrayLayout {
    /// A layout of `dims` (label, size), strides derived, no offset.
    pub fn of(dims: &[(&str, u32)]) -> Self {
        let mut stride: u32 = dims.iter().map(|d| d.1).product();
        let dim = dims
            .iter()
            .map(|&(label, size)| {
                let d = MultiArrayDimension {
                    label: label.to_owned(),
                    size,
                    stride,
                };
                stride = stride.checked_div(size).unwrap_or(0);
                d
            })
            .collect();
        Self {
            dim,
            data_offset: 0,
        }
    }
}

/// `std_msgs/msg/Float32MultiArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Float32MultiArray {
    /// How `data` is laid out.
    pub layout: MultiArrayLayout,
    /// The numbers.
    pub data: Vec<f32>,
}
message!(Float32MultiArray, FLOAT32_MULTI_ARRAY);

/// `std_msgs/msg/Float64MultiArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64MultiArray {
    /// How `data` is laid out.
    pub layout: MultiArrayLayout,
    /// The numbers.
    pub data: Vec<f64>,
}
message!(Float64MultiArray, FLOAT64_MULTI_ARRAY);

/// `std_msgs/msg/UInt32MultiArray`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct UInt32MultiArray {
    /// How `data` is laid out.
    pub layout: MultiArrayLayout,
    /// The numbers.
    pub data: Vec<u32>,
}
message!(UInt32MultiArray, UINT32_MULTI_ARRAY);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_definition_appends_each_used_type_once() {
        let text = defs::PATH.ros2msg();
        assert!(text.starts_with("std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n"));
        for used in [
            "MSG: std_msgs/Header\n",
            "MSG: builtin_interfaces/Time\n",
            "MSG: geometry_msgs/PoseStamped\n",
            "MSG: geometry_msgs/Pose\n",
            "MSG: geometry_msgs/Point\n",
            "MSG: geometry_msgs/Quaternion\n",
        ] {
            assert_eq!(text.matches(used).count(), 1, "{used} in\n{text}");
        }
        assert_eq!(defs::TF_MESSAGE.full_name(), "tf2_msgs/msg/TFMessage");
        assert_eq!(
            defs::TF_MESSAGE.dds_name(),
            "tf2_msgs::msg::dds_::TFMessage_"
        );
    }

    #[test]
    fn cdr_has_the_little_endian_header_and_aligned_fields() {
        let bytes = encode(&Float64 { data: 1.5 }).unwrap();
        // Encapsulation CDR_LE, then 8-byte alignment from after the header.
        assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        assert_eq!(bytes.len(), 12);
        assert_eq!(f64::from_le_bytes(bytes[4..12].try_into().unwrap()), 1.5);
        let text = encode(&Text { data: "ab".into() }).unwrap();
        // Length with the terminating NUL, then the bytes and the NUL.
        assert_eq!(&text[4..], &[3, 0, 0, 0, b'a', b'b', 0]);
    }
}
