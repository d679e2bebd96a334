"""Payload types as Python sees them, and the sample that carries them.

Numbers, text and bytes are Python's own; vectors, matrices, images and point clouds are numpy arrays;
an IMU reading, a GNSS fix, a CAN frame and a pose are small dataclasses.
"""

from dataclasses import dataclass, field
from typing import Any, Optional, Tuple

# Data type names, as diagrams, descriptors and `kairos components` spell them.
F64 = "f64"
I64 = "i64"
BOOL = "bool"
VECTOR = "vector"
MATRIX = "matrix"
TEXT = "text"
BYTES = "bytes"
IMAGE = "image"
POINT_CLOUD = "point_cloud"
IMU = "imu"
GNSS_FIX = "gnss_fix"
CAN_FRAME = "can_frame"
POSE = "pose"
#: An input filter accepting every type.
ANY = "any"

BUILT_IN_TYPES = (F64, I64, BOOL, VECTOR, MATRIX, TEXT, BYTES, IMAGE, POINT_CLOUD, IMU, GNSS_FIX, CAN_FRAME, POSE)

#: Image pixel formats and their channels per pixel; numpy arrays are (height, width) for grey and
#: (height, width, channels) for the others.
PIXEL_FORMATS = {
    "gray8": 1,
    "gray16": 1,
    "rgb8": 3,
    "rgba8": 4,
    "bgr8": 3,
    "bgra8": 4,
}

Vec3 = Tuple[float, float, float]
Quat = Tuple[float, float, float, float]


@dataclass(frozen=True)
class Imu:
    """An inertial measurement: rad/s and m/s² in the body frame, gravity included."""

    angular_velocity: Vec3
    linear_acceleration: Vec3
    #: (x, y, z, w), when the unit gives one.
    orientation: Optional[Quat] = None


#: GNSS fix qualities, as `GnssFix.status` spells them.
FIX_STATUSES = ("no_fix", "fix", "differential", "rtk_fixed")


@dataclass(frozen=True)
class GnssFix:
    """A satellite navigation fix (WGS84 degrees, metres above the ellipsoid, one-sigma accuracies)."""

    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    horizontal_accuracy_m: float = 0.0
    vertical_accuracy_m: float = 0.0
    status: str = "fix"

    def __post_init__(self):
        if self.status not in FIX_STATUSES:
            raise ValueError(f"GnssFix status {self.status!r} is not one of {', '.join(FIX_STATUSES)}")


@dataclass(frozen=True)
class CanFrame:
    """A CAN or CAN FD frame (more than 8 data bytes, or ``fd``, makes it FD; at most 64), or a remote
    request (``remote``: no data, asking for ``remote_length`` bytes, at most 8)."""

    id: int
    data: bytes = b""
    extended: bool = False
    fd: bool = False
    remote: bool = False
    remote_length: int = 0

    def __post_init__(self):
        if len(self.data) > 64:
            raise ValueError(f"a CAN frame carries at most 64 bytes, got {len(self.data)}")
        if self.remote and (self.data or not 0 <= self.remote_length <= 8):
            raise ValueError("a remote request carries no data and asks for 0 to 8 bytes")
        limit = 0x1FFFFFFF if self.extended else 0x7FF
        if not 0 <= self.id <= limit:
            raise ValueError(f"CAN id {self.id:#x} does not fit {'29' if self.extended else '11'} bits")


@dataclass(frozen=True)
class Pose:
    """A position in metres and an orientation quaternion (x, y, z, w)."""

    position: Vec3
    orientation: Quat = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Custom:
    """Data of a pack-defined type, in that pack's own encoding."""

    type_name: str
    data: bytes


@dataclass
class Sample:
    """One sample: its data and both of its times (nanoseconds on the runtime clock).

    `timestamp` is when the data originated, carried unchanged downstream; `time_of_issue` when it was
    last written to an output; `sequence` its position in that output's stream.
    """

    data: Any
    timestamp: int
    time_of_issue: int = 0
    sequence: int = 0
    #: The data type's name (`f64`, `image`, ...).
    type: str = ""
    #: For images: the pixel format (`rgb8`, `gray8`, ...).
    format: Optional[str] = None
    #: For point clouds: one intensity per point (a float32 array), when the sensor gives it.
    intensity: Any = None
    # The runtime's hold on shared pixels, released when the array is garbage collected.
    _handle: int = field(default=0, repr=False, compare=False)

    @property
    def seconds(self) -> float:
        """The timestamp in seconds."""
        return self.timestamp / 1e9
