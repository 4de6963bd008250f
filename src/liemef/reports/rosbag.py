r"""ROS 1 and ROS 2 bags as recorded logs, read with the pure-Python `rosbags <https://ternaris.gitlab.io/rosbags/>`_
package (no ROS install).

:func:`read_bag` turns the topics of a bag into the :class:`~liemef.reports.io.RecordedLog` that
:func:`~liemef.reports.io.read_log` returns for CSV and NPZ, by a **mapping** from topics to the system's columns
(``liemef schema SYSTEM`` prints them)::

    {"/imu":  {"type": "sensor_msgs/Imu"},
     "/fix":  {"type": "sensor_msgs/NavSatFix", "origin": [52.0, 4.3, 0.0]},
     "/odom": {"columns": {"v_x": "twist.twist.linear.x", "omega": "twist.twist.angular.z"}, "stamp": "bag"}}

Per topic (a JSON or TOML file, or a dict):

* ``columns``: system column -> field of the message, a dotted path to a number (``angular_velocity.x``), or a
  derived field: ``<quaternion>.r11`` .. ``<quaternion>.r33``, the entries of the rotation matrix of a
  ``geometry_msgs/Quaternion`` (``pose.orientation.r12``), and, for a ``NavSatFix``, ``enu.x``, ``enu.y``,
  ``enu.z``, the fix in local east-north-up metres (:func:`geodetic_to_enu`). Without ``columns``, the defaults of
  the message type (:data:`DEFAULT_COLUMNS`) fill those of the system's columns that exist with the same unit.
* ``type`` (optional): ``sensor_msgs/Imu``, ``nav_msgs/Odometry``, ``sensor_msgs/NavSatFix`` or
  ``geometry_msgs/PoseStamped`` (ROS 2 spelling ``sensor_msgs/msg/Imu`` too); it must be the bag's type of the
  topic. A topic of another type is read only with explicit ``columns``.
* ``stamp``: ``"header"`` (default: the message's ``header.stamp``, the time the sample was taken) or ``"bag"``
  (the time it was recorded).
* ``origin`` (NavSatFix): ``[latitude_deg, longitude_deg, altitude_m]`` of the ENU origin; default: the topic's
  first fix. Fixes with ``status.status < 0`` (no fix) are skipped.

Time grid: the union of the topics' time stamps, in seconds (``ns / 10**9``, correctly rounded), one row per
distinct time. Each topic's values sit at its own time stamps and are NaN elsewhere: a missing input holds the
previous one, a missing measurement has no weight (the conventions of ``docs/concepts.md``). The log starts at the
first time at which every input column has had a sample (earlier rows would hold an input never measured).
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .io import ROS2_FILES, LogLayout, RecordedLog, _check_log, read_json

MESSAGE_TYPES = {
    "sensor_msgs/msg/Imu": ("sensor_msgs/Imu", "imu"),
    "nav_msgs/msg/Odometry": ("nav_msgs/Odometry", "odometry"),
    "sensor_msgs/msg/NavSatFix": ("sensor_msgs/NavSatFix", "navsatfix"),
    "geometry_msgs/msg/PoseStamped": ("geometry_msgs/PoseStamped", "pose"),
}
"""The message types with default columns: the ROS 2 name and its accepted aliases (the ROS 1 name, a short one)."""

_XYZ = ("x", "y", "z")
_R = tuple(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))

DEFAULT_COLUMNS: dict[str, dict[str, tuple[str, str]]] = {
    "sensor_msgs/msg/Imu": {
        **{f"gyro_{a}": (f"angular_velocity.{a}", "rad/s") for a in _XYZ},
        **{f"acc_{a}": (f"linear_acceleration.{a}", "m/s^2") for a in _XYZ},
    },
    "nav_msgs/msg/Odometry": {
        **{f"omega_{a}": (f"twist.twist.angular.{a}", "rad/s") for a in _XYZ},
        **{f"v_{a}": (f"twist.twist.linear.{a}", "m/s") for a in _XYZ},
        "omega": ("twist.twist.angular.z", "rad/s"),
    },
    "sensor_msgs/msg/NavSatFix": {
        **{f"gnss_{a}": (f"enu.{a}", "m") for a in _XYZ},
        **{f"gps_{a}": (f"enu.{a}", "m") for a in _XYZ},
        **{f"position_{a}": (f"enu.{a}", "m") for a in _XYZ},
    },
    "geometry_msgs/msg/PoseStamped": {
        **{f"position_{a}": (f"pose.position.{a}", "m") for a in _XYZ},
        **{f"attitude_{r}": (f"pose.orientation.{r}", "1") for r in _R},
    },
}
"""Per message type: system column -> (field, unit). A default fills a column of the system's that has the same
name and unit: ``inertial_navigation``'s gyro and accelerometer and GNSS, ``pose3d``'s twist, position and
attitude, ``planar_localization``'s odometry and GPS. An ``Odometry``'s defaults are its twist only: its pose is
the integral of that twist, not an independent fix (map ``pose.pose.position.x`` etc. explicitly if it is one)."""

WGS84_A = 6378137.0
"""WGS-84 semi-major axis (m)."""
WGS84_F = 1.0 / 298.257223563
"""WGS-84 flattening."""


def geodetic_to_enu(lat_deg, lon_deg, alt, origin) -> np.ndarray:
    r"""WGS-84 latitude, longitude (degrees) and ellipsoidal altitude (m) to east-north-up metres about
    ``origin = (lat0, lon0, alt0)``, shape (N, 3).

    Exact (no small-distance approximation): each point to Earth-centred Earth-fixed coordinates,
    $X = (N + h)\cos\varphi\cos\lambda$, $Y = (N + h)\cos\varphi\sin\lambda$, $Z = (N(1 - e^2) + h)\sin\varphi$
    with $N = a/\sqrt{1 - e^2\sin^2\varphi}$, then the difference to the origin rotated into the origin's
    tangent plane: $e = -\sin\lambda_0\,dX + \cos\lambda_0\,dY$,
    $n = -\sin\varphi_0\cos\lambda_0\,dX - \sin\varphi_0\sin\lambda_0\,dY + \cos\varphi_0\,dZ$,
    $u = \cos\varphi_0\cos\lambda_0\,dX + \cos\varphi_0\sin\lambda_0\,dY + \sin\varphi_0\,dZ$.
    Near the origin $e \approx N_0\cos\varphi_0\,d\lambda$, $n \approx M_0\,d\varphi$ (meridian radius $M_0$)."""
    e2 = WGS84_F * (2.0 - WGS84_F)

    def ecef(lat, lon, h):
        phi, lam = np.radians(lat), np.radians(lon)
        N = WGS84_A / np.sqrt(1.0 - e2 * np.sin(phi) ** 2)
        return np.stack([(N + h) * np.cos(phi) * np.cos(lam), (N + h) * np.cos(phi) * np.sin(lam),
                         (N * (1.0 - e2) + h) * np.sin(phi)], axis=-1)

    lat0, lon0, h0 = (float(v) for v in origin)
    d = ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(alt, float)) - ecef(lat0, lon0, h0)
    p0, l0 = math.radians(lat0), math.radians(lon0)
    R = np.array([[-math.sin(l0), math.cos(l0), 0.0],
                  [-math.sin(p0) * math.cos(l0), -math.sin(p0) * math.sin(l0), math.cos(p0)],
                  [math.cos(p0) * math.cos(l0), math.cos(p0) * math.sin(l0), math.sin(p0)]])
    return d.reshape(-1, 3) @ R.T


def quaternion_matrix(x, y, z, w) -> np.ndarray:
    """The rotation matrix of the quaternion ``(x, y, z, w)`` (normalized first), ROS's order and convention:
    the orientation of the child (body) frame in the parent (world) frame, body to world."""
    q = np.array([w, x, y, z], dtype=np.float64)
    nq = np.linalg.norm(q)
    if not nq > 0:
        raise ValueError(f"orientation: expected a nonzero quaternion, got (x, y, z, w) = {(x, y, z, w)}")
    w, x, y, z = q / nq
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _canonical_type(name: str, where: str) -> str:
    for canon, aliases in MESSAGE_TYPES.items():
        if name == canon or name in aliases:
            return canon
    known = [a[0] for a in MESSAGE_TYPES.values()]
    raise ValueError(f"{where}: expected a message type among {known}, got {name!r}")


@dataclass(frozen=True)
class _Topic:
    topic: str
    columns: dict[str, str]
    stamp: str
    origin: tuple[float, float, float] | None


def read_mapping(mapping: Mapping[str, Any] | str | os.PathLike) -> dict[str, dict[str, Any]]:
    """A topic mapping from a dict, or from a ``.json`` or ``.toml`` file (ValueError naming ``mapping``)."""
    if isinstance(mapping, str | os.PathLike):
        p = Path(mapping)
        if p.suffix.lower() == ".toml":
            if not p.is_file():
                raise ValueError(f"mapping: file not found: {str(p)!r}")
            try:
                mapping = tomllib.loads(p.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
                raise ValueError(f"mapping: cannot read {str(p)!r} as TOML ({err})") from err
        elif p.suffix.lower() == ".json":
            mapping = read_json(p, "mapping")
        else:
            raise ValueError(f"mapping: expected a .json or .toml file, got {str(p)!r}")
    if not isinstance(mapping, Mapping) or not mapping:
        raise ValueError(f"mapping: expected a non-empty table of topics, got {mapping!r}")
    out = {}
    for topic, spec in mapping.items():
        if not isinstance(spec, Mapping):
            raise ValueError(f"mapping[{topic!r}]: expected a table (type, columns, stamp, origin), got {spec!r}")
        extra = sorted(set(spec) - {"type", "columns", "stamp", "origin"})
        if extra:
            raise ValueError(f"mapping[{topic!r}]: expected the keys type, columns, stamp, origin, got {extra}")
        out[str(topic)] = dict(spec)
    return out


def _plan(mapping: dict[str, dict[str, Any]], bag_types: Mapping[str, str], layout: LogLayout,
          units: Mapping[str, str] | None) -> list[_Topic]:
    """Check the mapping against the bag's topics and the system's columns; the columns each topic fills."""
    names = set(layout.inputs) | set(layout.outputs)
    filled: dict[str, str] = {}
    plan = []
    for topic, spec in mapping.items():
        where = f"mapping[{topic!r}]"
        if topic not in bag_types:
            raise ValueError(f"{where}: expected a topic of the bag, one of {sorted(bag_types)}, got {topic!r}")
        bag_type = bag_types[topic]
        known = next((c for c in MESSAGE_TYPES if c == bag_type), None)
        if "type" in spec:
            want = _canonical_type(str(spec["type"]), f"{where}['type']")
            if want != bag_type:
                raise ValueError(f"{where}['type']: expected the bag's type of the topic, {bag_type!r}, got "
                                 f"{spec['type']!r}")
        if "columns" in spec:
            cols = spec["columns"]
            if not isinstance(cols, Mapping) or not cols:
                raise ValueError(f"{where}['columns']: expected a table column -> field, got {cols!r}")
            cols = {str(k): str(v) for k, v in cols.items()}
            bad = sorted(set(cols) - names)
            if bad:
                raise ValueError(f"{where}['columns']: expected columns of the system, among "
                                 f"{[*layout.inputs, *layout.outputs]}, got {bad}")
        elif known is None:
            raise ValueError(f"{where}: the topic's type {bag_type!r} has no default columns; expected one of "
                             f"{[a[0] for a in MESSAGE_TYPES.values()]} or explicit 'columns'")
        else:
            cols = {c: f for c, (f, unit) in DEFAULT_COLUMNS[known].items()
                    if c in names and (units is None or units.get(c) == unit)}
            if not cols:
                raise ValueError(f"{where}: no column of the system matches the defaults of {bag_type} "
                                 f"({sorted(DEFAULT_COLUMNS[known])}); expected explicit 'columns' for the system's "
                                 f"{[*layout.inputs, *layout.outputs]}")
        for c in cols:
            if c in filled:
                raise ValueError(f"{where}: column {c!r} is filled by topic {filled[c]!r} already; expected each "
                                 f"column from one topic")
            filled[c] = topic
        stamp = spec.get("stamp", "header")
        if stamp not in ("header", "bag"):
            raise ValueError(f"{where}['stamp']: expected 'header' or 'bag', got {stamp!r}")
        origin = spec.get("origin")
        if origin is not None:
            try:
                origin = tuple(float(v) for v in origin)
            except (TypeError, ValueError):
                origin = ()
            if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
                raise ValueError(f"{where}['origin']: expected [latitude_deg, longitude_deg, altitude_m], got "
                                 f"{spec['origin']!r}")
        plan.append(_Topic(topic, cols, stamp, origin))
    missing = [c for c in layout.inputs if c not in filled]
    if missing:
        raise ValueError(f"mapping: expected every input column filled by a topic, got no topic for {missing}")
    return plan


def _field(msg, path: str, where: str):
    obj = msg
    for part in path.split("."):
        if not hasattr(obj, part):
            fields = [f for f in getattr(obj, "__dataclass_fields__", {}) if not f.startswith("__")]
            raise ValueError(f"{where}: expected a field of the message, got {path!r} ({part!r} is not among "
                             f"{fields})")
        obj = getattr(obj, part)
    return obj


def _value(msg, path: str, where: str, enu: np.ndarray | None) -> float:
    """The number at ``path`` in ``msg``, or a derived field (``enu.*``, ``<quaternion>.rIJ``)."""
    head, _, last = path.rpartition(".")
    if head == "enu" and enu is not None and last in _XYZ:
        return float(enu[_XYZ.index(last)])
    if last in _R and head:
        q = _field(msg, head, where)
        if all(hasattr(q, a) for a in ("x", "y", "z", "w")):
            i, j = int(last[1]) - 1, int(last[2]) - 1
            try:
                return float(quaternion_matrix(q.x, q.y, q.z, q.w)[i, j])
            except ValueError as err:  # e.g. an IMU without an orientation estimate sends zeros
                raise ValueError(f"{where}: {err} at {head!r}") from err
    v = _field(msg, path, where)
    if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
        raise ValueError(f"{where}: expected a number at {path!r}, got {type(v).__name__}")
    return float(v)


def _bag_paths(path: str | os.PathLike) -> Path:
    """The bag: a ROS 1 ``.bag`` file or a ROS 2 bag folder (a file inside it stands for the folder)."""
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"bag: expected a path (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    if not p.exists():
        raise ValueError(f"bag: expected a ROS 1 .bag file or a ROS 2 bag folder, got {str(p)!r} (not found)")
    if p.is_file() and p.suffix.lower() in ROS2_FILES and (p.parent / "metadata.yaml").is_file():
        p = p.parent
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        raise ValueError(f"bag: expected a ROS 2 bag folder with a metadata.yaml, got the folder {str(p)!r}")
    if p.is_file() and p.suffix.lower() != ".bag":
        raise ValueError(f"bag: expected a ROS 1 .bag file or a ROS 2 bag folder, got {str(p)!r}")
    return p


def _seconds(ns: int) -> float:
    return int(ns) / 10**9  # int / int: correctly rounded


def read_bag(path: str | os.PathLike, mapping, system_or_input_dim, output_dim: int | None = None) -> RecordedLog:
    """A ROS 1 ``.bag`` file or a ROS 2 bag folder as a recorded log for ``system`` (its columns) or for
    ``input_dim`` inputs and ``output_dim`` outputs (``u1..um``, ``y1..yp``), by the topic ``mapping`` (a dict
    or a JSON/TOML file; see the module docstring).

    ValueError naming the argument, the expected and the received value on: a missing file, a topic not in the
    bag, a message type without defaults and no explicit columns, a type that is not the bag's, a column the
    system does not have, a field the message does not have, an input column no topic fills, repeated time
    stamps within a topic, fewer than two samples."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if isinstance(system_or_input_dim, int | np.integer):
        layout = LogLayout.of(None, system_or_input_dim, output_dim)
        units = None
    else:
        layout = LogLayout.of(system_or_input_dim)
        iu, ou = getattr(system_or_input_dim, "input_units", None), getattr(system_or_input_dim, "output_units", None)
        units = None if iu is None or ou is None else dict(zip([*layout.inputs, *layout.outputs], [*iu, *ou],
                                                               strict=True))
    spec = read_mapping(mapping)
    p = _bag_paths(path)
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # noqa: BLE001 - rosbags raises its own errors for a bad bag
        raise ValueError(f"bag: cannot read {str(p)!r} as a ROS 1 or ROS 2 bag ({type(err).__name__}: {err})") from err
    try:
        bag_types = {c.topic: c.msgtype for c in reader.connections}
        plan = _plan(spec, bag_types, layout, units)
        streams = []
        for tp in plan:
            conns = [c for c in reader.connections if c.topic == tp.topic]
            cols = list(tp.columns)
            is_fix = bag_types[tp.topic] == "sensor_msgs/msg/NavSatFix"
            origin = tp.origin
            ts, rows = [], []
            for conn, t_bag, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                enu = None
                if is_fix:
                    lla = (float(msg.latitude), float(msg.longitude), float(msg.altitude))
                    if int(msg.status.status) < 0 or not all(math.isfinite(v) for v in lla):
                        continue  # no fix
                    origin = lla if origin is None else origin
                    enu = geodetic_to_enu(*lla, origin)[0]
                if tp.stamp == "header":
                    st = _field(msg, "header.stamp", f"mapping[{tp.topic!r}]['stamp']")
                    ns = int(st.sec) * 10**9 + int(st.nanosec)
                else:
                    ns = int(t_bag)
                ts.append(ns)
                rows.append([_value(msg, tp.columns[c], f"mapping[{tp.topic!r}]['columns'][{c!r}]", enu)
                             for c in cols])
            if len(set(ts)) != len(ts):
                raise ValueError(f"bag: expected distinct time stamps on topic {tp.topic!r} ({tp.stamp} stamps), "
                                 f"got {len(ts) - len(set(ts))} repeated")
            values = np.array(rows, dtype=np.float64).reshape(-1, len(cols))
            streams.append((np.array(ts, dtype=np.int64), cols, values))
    finally:
        reader.close()
    grid = np.unique(np.concatenate([s[0] for s in streams]))
    index = {c: k for k, c in enumerate([*layout.inputs, *layout.outputs])}
    data = np.full((grid.shape[0], len(index)), np.nan)
    for ns, cols, values in streams:
        rows = np.searchsorted(grid, ns)
        for k, c in enumerate(cols):
            data[rows, index[c]] = values[:, k]
    m = len(layout.inputs)
    start = 0
    if m:
        seen = np.cumsum(np.isfinite(data[:, :m]), axis=0) > 0
        full = np.all(seen, axis=1)
        if not full.any():
            raise ValueError(f"bag: expected samples of every input column, got none for "
                             f"{[c for c, s in zip(layout.inputs, seen[-1], strict=True) if not s]}")
        start = int(np.argmax(full))
        for k in range(m):  # the first row holds each input's last sample before it, as the filter would
            if start and not np.isfinite(data[start, k]):
                before = data[:start, k][np.isfinite(data[:start, k])]
                data[start, k] = before[-1]
    ts = np.array([_seconds(v) for v in grid[start:]], dtype=np.float64)
    return _check_log(ts, data[start:, :m], data[start:, m:], repr(str(p)), layout)
