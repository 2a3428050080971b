"""ROS 2's standard messages for Eclipse Cyclone DDS (PyPI `cyclonedds`), declared by hand
from their IDL with ROS 2's DDS type names (`pkg::msg::dds_::Type_`): what any ROS 2 node
on Cyclone DDS declares. Nothing here comes from TES."""

from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float32, float64, int32, sequence, uint8, uint32


def ros(package: str, name: str) -> str:
    return f"{package}::msg::dds_::{name}_"


@dataclass
class Time(IdlStruct, typename=ros("builtin_interfaces", "Time")):
    sec: int32
    nanosec: uint32


@dataclass
class Duration(IdlStruct, typename=ros("builtin_interfaces", "Duration")):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename=ros("std_msgs", "Header")):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename=ros("geometry_msgs", "Vector3")):
    x: float64
    y: float64
    z: float64


@dataclass
class Point(IdlStruct, typename=ros("geometry_msgs", "Point")):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename=ros("geometry_msgs", "Quaternion")):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename=ros("geometry_msgs", "Transform")):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename=ros("geometry_msgs", "TransformStamped")):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename=ros("tf2_msgs", "TFMessage")):
    transforms: sequence[TransformStamped]


@dataclass
class Pose(IdlStruct, typename=ros("geometry_msgs", "Pose")):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename=ros("geometry_msgs", "PoseStamped")):
    header: Header
    pose: Pose


@dataclass
class Path(IdlStruct, typename=ros("nav_msgs", "Path")):
    header: Header
    poses: sequence[PoseStamped]


@dataclass
class ColorRGBA(IdlStruct, typename=ros("std_msgs", "ColorRGBA")):
    r: float32
    g: float32
    b: float32
    a: float32


@dataclass
class CompressedImage(IdlStruct, typename=ros("sensor_msgs", "CompressedImage")):
    header: Header
    format: str
    data: sequence[uint8]


@dataclass
class UVCoordinate(IdlStruct, typename=ros("visualization_msgs", "UVCoordinate")):
    u: float32
    v: float32


@dataclass
class MeshFile(IdlStruct, typename=ros("visualization_msgs", "MeshFile")):
    filename: str
    data: sequence[uint8]


@dataclass
class Marker(IdlStruct, typename=ros("visualization_msgs", "Marker")):
    header: Header
    ns: str
    id: int32
    type: int32
    action: int32
    pose: Pose
    scale: Vector3
    color: ColorRGBA
    lifetime: Duration
    frame_locked: bool
    points: sequence[Point]
    colors: sequence[ColorRGBA]
    texture_resource: str
    texture: CompressedImage
    uv_coordinates: sequence[UVCoordinate]
    text: str
    mesh_resource: str
    mesh_file: MeshFile
    mesh_use_embedded_materials: bool


@dataclass
class MarkerArray(IdlStruct, typename=ros("visualization_msgs", "MarkerArray")):
    markers: sequence[Marker]


@dataclass
class Log(IdlStruct, typename=ros("rcl_interfaces", "Log")):
    stamp: Time
    level: uint8
    name: str
    msg: str
    file: str
    function: str
    line: uint32


@dataclass
class Float64(IdlStruct, typename=ros("std_msgs", "Float64")):
    data: float64


@dataclass
class UInt32(IdlStruct, typename=ros("std_msgs", "UInt32")):
    data: uint32


@dataclass
class String(IdlStruct, typename=ros("std_msgs", "String")):
    data: str


@dataclass
class Twist(IdlStruct, typename=ros("geometry_msgs", "Twist")):
    linear: Vector3
    angular: Vector3


@dataclass
class MultiArrayDimension(IdlStruct, typename=ros("std_msgs", "MultiArrayDimension")):
    label: str
    size: uint32
    stride: uint32


@dataclass
class MultiArrayLayout(IdlStruct, typename=ros("std_msgs", "MultiArrayLayout")):
    dim: sequence[MultiArrayDimension]
    data_offset: uint32


@dataclass
class Float32MultiArray(IdlStruct, typename=ros("std_msgs", "Float32MultiArray")):
    layout: MultiArrayLayout
    data: sequence[float32]


@dataclass
class Float64MultiArray(IdlStruct, typename=ros("std_msgs", "Float64MultiArray")):
    layout: MultiArrayLayout
    data: sequence[float64]


@dataclass
class UInt32MultiArray(IdlStruct, typename=ros("std_msgs", "UInt32MultiArray")):
    layout: MultiArrayLayout
    data: sequence[uint32]
