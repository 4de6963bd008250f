"""ROS 1 and ROS 2 bags as logs (liemef.reports.rosbag): bags written here with rosbags, read back exactly."""

import json
import math

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from liemef.groups import SO3
from liemef.reports.rosbag import WGS84_A, WGS84_F, geodetic_to_enu, quaternion_matrix, read_bag
from liemef.systems import inertial_navigation, planar_localization, pose3d
from tolerances import ROUNDOFF

T0 = 1_700_000_000  # s: epoch-scale stamps, as real bags have
IMU_NS = [k * 10_000_000 for k in range(8)]  # 100 Hz
FIX_NS = [25_000_000, 40_000_000, 65_000_000]  # between IMU samples, on one, between
POSE_NS = [15_000_000, 55_000_000]
FIXES = [(52.0, 4.3, 10.0), (52.00001, 4.30002, 10.5), (-1.0, -1.0, 0.0)]  # the last one has no fix (status -1)


def seconds(ns):
    return (T0 * 10**9 + ns) / 10**9


def rng_values():
    rng = np.random.default_rng(7)
    return {"gyro": rng.normal(size=(len(IMU_NS), 3)), "acc": rng.normal(size=(len(IMU_NS), 3)),
            "twist": rng.normal(size=(len(IMU_NS), 6)), "pos": rng.normal(size=(len(POSE_NS), 3)),
            "quat": rng.normal(size=(len(POSE_NS), 4))}


def write_bag(path, ros1: bool, mcap: bool = False):
    """A bag (ROS 1, or ROS 2 in SQLite or MCAP storage) with /imu (Imu), /odom (Odometry) at the IMU times (bag
    time = stamp + 1 ms), /fix (NavSatFix), /pose (PoseStamped) and /temp (std_msgs/Float64, no header)."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    V3, Q, P = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Point"]
    Pose, Twist = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Twist"]

    def header(ns):
        stamp = T["builtin_interfaces/msg/Time"](sec=T0 + ns // 10**9, nanosec=ns % 10**9)
        return T["std_msgs/msg/Header"](**({"seq": 0} if ros1 else {}), stamp=stamp, frame_id="base")

    v = rng_values()
    z9, z36 = np.zeros(9), np.zeros(36)
    msgs = {"/imu": [], "/odom": [], "/fix": [], "/pose": [], "/temp": []}
    for k, ns in enumerate(IMU_NS):
        msgs["/imu"].append((ns, T["sensor_msgs/msg/Imu"](
            header=header(ns), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=z9,
            angular_velocity=V3(*v["gyro"][k]), angular_velocity_covariance=z9,
            linear_acceleration=V3(*v["acc"][k]), linear_acceleration_covariance=z9)))
        tw = v["twist"][k]
        msgs["/odom"].append((ns, T["nav_msgs/msg/Odometry"](
            header=header(ns), child_frame_id="base",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=Pose(position=P(0.0, 0.0, 0.0),
                                                                       orientation=Q(0.0, 0.0, 0.0, 1.0)),
                                                             covariance=z36),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=Twist(linear=V3(*tw[3:]), angular=V3(*tw[:3])),
                                                               covariance=z36))))
        msgs["/temp"].append((ns, T["std_msgs/msg/Float64"](data=float(k))))
    for ns, (lat, lon, alt) in zip(FIX_NS, FIXES, strict=True):
        status = T["sensor_msgs/msg/NavSatStatus"](status=-1 if lat < 0 else 0, service=1)
        msgs["/fix"].append((ns, T["sensor_msgs/msg/NavSatFix"](
            header=header(ns), status=status, latitude=lat, longitude=lon, altitude=alt,
            position_covariance=z9, position_covariance_type=0)))
    for k, ns in enumerate(POSE_NS):
        msgs["/pose"].append((ns, T["geometry_msgs/msg/PoseStamped"](
            header=header(ns), pose=Pose(position=P(*v["pos"][k]), orientation=Q(*v["quat"][k])))))
    plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=plugin)
    with writer as w:
        for topic, items in msgs.items():
            typ = items[0][1].__msgtype__
            conn = w.add_connection(topic, typ, typestore=store)
            for ns, msg in items:
                data = store.serialize_ros1(msg, typ) if ros1 else store.serialize_cdr(msg, typ)
                w.write(conn, T0 * 10**9 + ns + 1_000_000, data)
    return path


@pytest.fixture(scope="module", params=["ros1", "ros2", "ros2-mcap"])
def bag(request, tmp_path_factory):
    ros1 = request.param == "ros1"
    return write_bag(tmp_path_factory.mktemp("bags") / ("test.bag" if ros1 else request.param), ros1,
                     mcap=request.param == "ros2-mcap")


def test_imu_and_fixes_fill_inertial_navigation_on_the_union_of_their_times(bag):
    log = read_bag(bag, {"/imu": {"type": "sensor_msgs/Imu"}, "/fix": {"type": "sensor_msgs/NavSatFix"}},
                   inertial_navigation())
    grid = sorted(set(IMU_NS) | set(FIX_NS[:2]))  # the third fix has no fix
    np.testing.assert_array_equal(log.ts, [seconds(ns) for ns in grid])
    v = rng_values()
    imu_rows = [grid.index(ns) for ns in IMU_NS]
    np.testing.assert_array_equal(log.us[imu_rows], np.hstack([v["gyro"], v["acc"]]))
    other = np.setdiff1d(np.arange(len(grid)), imu_rows)
    assert np.isnan(log.us[other]).all()
    fix_rows = [grid.index(ns) for ns in FIX_NS[:2]]
    np.testing.assert_array_equal(log.ys[fix_rows[0]], [0.0, 0.0, 0.0])  # the ENU origin is the first fix
    np.testing.assert_array_equal(log.ys[fix_rows[1]], geodetic_to_enu(*FIXES[1], FIXES[0])[0])
    assert np.isnan(np.delete(log.ys, fix_rows, axis=0)).all()


def test_an_explicit_origin_and_the_ros2_type_spelling(bag):
    origin = (52.0, 4.3, 0.0)
    log = read_bag(bag, {"/imu": {"type": "sensor_msgs/msg/Imu"},
                         "/fix": {"type": "navsatfix", "origin": list(origin)}}, inertial_navigation())
    rows = np.isfinite(log.ys[:, 0])
    np.testing.assert_array_equal(log.ys[rows], [geodetic_to_enu(*fix, origin)[0] for fix in FIXES[:2]])


def test_odometry_twist_and_pose_stamped_fill_pose3d_with_the_rotation_matrix(bag):
    log = read_bag(bag, {"/odom": {}, "/pose": {}}, pose3d(fixes="pose"))
    grid = sorted(set(IMU_NS) | set(POSE_NS))
    np.testing.assert_array_equal(log.ts, [seconds(ns) for ns in grid])
    v = rng_values()
    np.testing.assert_array_equal(log.us[[grid.index(ns) for ns in IMU_NS]], v["twist"])
    rows = [grid.index(ns) for ns in POSE_NS]
    np.testing.assert_array_equal(log.ys[rows, :3], v["pos"])
    for k, r in enumerate(rows):
        x, y, z, w = v["quat"][k]
        R = np.asarray(SO3(np.array([w, x, y, z]) / np.linalg.norm(v["quat"][k])).as_matrix())
        np.testing.assert_allclose(log.ys[r, 3:].reshape(3, 3), R, atol=ROUNDOFF)
        np.testing.assert_array_equal(log.ys[r, 3:].reshape(3, 3), quaternion_matrix(x, y, z, w))


def test_planar_odometry_and_gps_from_a_toml_mapping_with_bag_stamps(bag, tmp_path):
    mapping = tmp_path / "topics.toml"
    mapping.write_text('["/odom"]\nstamp = "bag"\n["/fix"]\ntype = "sensor_msgs/NavSatFix"\n')
    log = read_bag(bag, mapping, planar_localization())
    grid = sorted({ns + 1_000_000 for ns in IMU_NS} | set(FIX_NS[:2]))  # odometry at its recording time
    np.testing.assert_array_equal(log.ts, [seconds(ns) for ns in grid])
    v = rng_values()
    rows = [grid.index(ns + 1_000_000) for ns in IMU_NS]
    np.testing.assert_array_equal(log.us[rows], v["twist"][:, [3, 4, 2]])  # v_x, v_y, omega
    fix = [grid.index(ns) for ns in FIX_NS[:2]]
    np.testing.assert_array_equal(log.ys[fix], [geodetic_to_enu(*f, FIXES[0])[0, :2] for f in FIXES[:2]])


def test_explicit_columns_read_any_message_type_and_a_json_mapping(bag, tmp_path):
    mapping = tmp_path / "topics.json"
    mapping.write_text(json.dumps({"/imu": {"columns": {"u1": "angular_velocity.z"}},
                                   "/temp": {"columns": {"y1": "data"}, "stamp": "bag"}}))
    log = read_bag(bag, mapping, 1, 1)
    assert log.ts.shape == (2 * len(IMU_NS),)
    np.testing.assert_array_equal(log.ys[np.isfinite(log.ys[:, 0]), 0], np.arange(len(IMU_NS)))
    np.testing.assert_array_equal(log.us[np.isfinite(log.us[:, 0]), 0], rng_values()["gyro"][:, 2])


def test_the_log_starts_when_every_input_has_a_sample(bag):
    log = read_bag(bag, {"/imu": {"columns": {"gyro_x": "angular_velocity.x", "gyro_y": "angular_velocity.y",
                                              "gyro_z": "angular_velocity.z"}},
                         "/pose": {"columns": {"acc_x": "pose.position.x", "acc_y": "pose.position.y",
                                               "acc_z": "pose.position.z"}}},
                   inertial_navigation())
    assert log.ts[0] == seconds(POSE_NS[0])
    # the first row holds the gyro's last sample before it, as the filter would
    np.testing.assert_array_equal(log.us[0], [*rng_values()["gyro"][1], *rng_values()["pos"][0]])


@pytest.mark.parametrize("mapping, match", [
    ({"/imu": {}, "/gnss": {}}, r"mapping\['/gnss'\]: expected a topic of the bag, one of \['/fix', '/imu'"),
    ({"/imu": {}, "/temp": {}}, r"mapping\['/temp'\]: the topic's type 'std_msgs/msg/Float64' has no default "
                                r"columns; expected one of"),
    ({"/imu": {"type": "sensor_msgs/Magnetometer"}}, r"mapping\['/imu'\]\['type'\]: expected a message type among "
                                                     r"\['sensor_msgs/Imu'.*got 'sensor_msgs/Magnetometer'"),
    ({"/imu": {"type": "nav_msgs/Odometry"}}, r"expected the bag's type of the topic, 'sensor_msgs/msg/Imu', got "
                                              r"'nav_msgs/Odometry'"),
    ({"/imu": {}, "/fix": {"columns": {"gnss_w": "enu.x"}}}, r"mapping\['/fix'\]\['columns'\]: expected columns of "
                                                             r"the system, among \['gyro_x'.*got \['gnss_w'\]"),
    ({"/imu": {}, "/fix": {"columns": {"gnss_x": "latitud"}}}, r"\['columns'\]\['gnss_x'\]: expected a field of the "
                                                               r"message, got 'latitud'"),
    ({"/fix": {}}, r"mapping: expected every input column filled by a topic, got no topic for \['gyro_x'"),
    ({"/imu": {}, "/odom": {"columns": {"gyro_x": "twist.twist.angular.x"}}}, r"column 'gyro_x' is filled by "
                                                                              r"topic '/imu' already"),
    ({"/imu": {}, "/fix": {"columns": {"gnss_x": "orientation.r11"}}}, r"\['gnss_x'\]: expected a field of the "
                                                                         r"message, got 'orientation'"),
    ({"/imu": {"stamp": "now"}}, r"\['stamp'\]: expected 'header' or 'bag', got 'now'"),
    ({"/imu": {}, "/fix": {"origin": [52.0, 4.3]}}, r"\['origin'\]: expected \[latitude_deg, longitude_deg, "
                                                    r"altitude_m\], got \[52.0, 4.3\]"),
    ({"/imu": {"colums": {}}}, r"mapping\['/imu'\]: expected the keys type, columns, stamp, origin, got \['colums'\]"),
    ({}, r"mapping: expected a non-empty table of topics"),
])
def test_bad_mappings_name_the_argument_the_expected_and_the_received(bag, mapping, match):
    with pytest.raises(ValueError, match=match):
        read_bag(bag, mapping, inertial_navigation())


def test_bad_bag_paths(tmp_path):
    with pytest.raises(ValueError, match=r"bag: expected a ROS 1 .bag file or a ROS 2 bag folder, got .*not found"):
        read_bag(tmp_path / "none.bag", {"/imu": {}}, inertial_navigation())
    with pytest.raises(ValueError, match=r"bag: expected a ROS 2 bag folder with a metadata.yaml"):
        read_bag(tmp_path, {"/imu": {}}, inertial_navigation())
    (tmp_path / "x.bag").write_bytes(b"not a bag")
    with pytest.raises(ValueError, match=r"bag: cannot read .*x.bag.* as a ROS 1 or ROS 2 bag"):
        read_bag(tmp_path / "x.bag", {"/imu": {}}, inertial_navigation())
    with pytest.raises(ValueError, match=r"mapping: expected a .json or .toml file"):
        read_bag(tmp_path / "x.bag", str(tmp_path / "topics.txt"), inertial_navigation())


def test_enu_closed_forms():
    a, b = WGS84_A, WGS84_A * (1 - WGS84_F)
    # Quarter turns of the equator and the pole from (0, 0, 0): the ECEF differences are (-a, a, 0), (-a, 0, b).
    np.testing.assert_allclose(geodetic_to_enu(0.0, 90.0, 0.0, (0.0, 0.0, 0.0)), [[a, 0.0, -a]], atol=1e-8)
    np.testing.assert_allclose(geodetic_to_enu(90.0, 0.0, 0.0, (0.0, 0.0, 0.0)), [[0.0, b, -a]], atol=1e-8)
    # Straight up is up, exactly in direction.
    np.testing.assert_allclose(geodetic_to_enu(52.0, 4.3, 110.0, (52.0, 4.3, 10.0)), [[0.0, 0.0, 100.0]],
                               atol=1e-8)
    # Small steps: east N cos(phi) dlambda, north M dphi (radii of curvature of the ellipsoid).
    phi, d = math.radians(52.0), 1e-7
    e2 = WGS84_F * (2 - WGS84_F)
    N = a / math.sqrt(1 - e2 * math.sin(phi) ** 2)
    M = a * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    east = geodetic_to_enu(52.0, 4.3 + math.degrees(d), 0.0, (52.0, 4.3, 0.0))[0]
    north = geodetic_to_enu(52.0 + math.degrees(d), 4.3, 0.0, (52.0, 4.3, 0.0))[0]
    np.testing.assert_allclose(east, [N * math.cos(phi) * d, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(north, [0.0, M * d, 0.0], atol=1e-6)


def write_planar_bag(path):
    """A ROS 2 bag: /odom at 100 Hz driving east at 1 m/s for 0.5 s, /fix at 10 Hz on that line."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    V3, Q, P = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Point"]

    def header(ns):
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=T0 + ns // 10**9,
                                                                               nanosec=ns % 10**9), frame_id="b")

    z9, z36 = np.zeros(9), np.zeros(36)
    lat0, lon0 = 52.0, 4.3
    east_deg = math.degrees(1.0 / (WGS84_A * math.cos(math.radians(lat0))))  # about 1 m of longitude
    with Writer2(path, version=9) as w:
        odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        fix = w.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=store)
        for k in range(50):
            ns = k * 10_000_000
            msg = T["nav_msgs/msg/Odometry"](
                header=header(ns), child_frame_id="b",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                    position=P(0.0, 0.0, 0.0), orientation=Q(0.0, 0.0, 0.0, 1.0)), covariance=z36),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                    linear=V3(1.0, 0.0, 0.0), angular=V3(0.0, 0.0, 0.0)), covariance=z36))
            w.write(odom, T0 * 10**9 + ns, store.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
            if k % 10 == 5:
                msg = T["sensor_msgs/msg/NavSatFix"](
                    header=header(ns + 1_000_000), status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                    latitude=lat0, longitude=lon0 + east_deg * (ns + 1_000_000) / 1e9, altitude=0.0,
                    position_covariance=z9, position_covariance_type=0)
                w.write(fix, T0 * 10**9 + ns, store.serialize_cdr(msg, "sensor_msgs/msg/NavSatFix"))
    return path


def test_cli_run_filters_a_bag_and_writes_a_tum_trajectory(tmp_path):
    from click.testing import CliRunner

    from liemef.cli import cli
    from liemef.reports.io import read_tum

    bag = write_planar_bag(tmp_path / "planar")
    topics = tmp_path / "topics.json"
    topics.write_text(json.dumps({"/odom": {}, "/fix": {"origin": [52.0, 4.3, 0.0]}}))
    run = lambda *a: CliRunner().invoke(cli, ["run", "--system", "localization", "--log", str(bag), *a,  # noqa: E731
                                              "--no-progress"], catch_exceptions=False)
    res = run("--topics", str(topics), "--tum", "--out", str(tmp_path / "out"))
    assert res.exit_code == 0, res.output
    est = np.loadtxt(tmp_path / "out" / "estimates.csv", delimiter=",", skiprows=1)
    ts, (p, q) = read_tum(tmp_path / "out" / "estimates.tum")
    assert ts.shape == (55,)  # 50 odometry samples and 5 fixes between them
    np.testing.assert_array_equal(ts, est[:, 0])
    np.testing.assert_array_equal(p[:, :2], est[:, 2:4])  # (x, y, 0): SE(2) lifted to 3D
    np.testing.assert_array_equal(p[:, 2], 0.0)
    np.testing.assert_allclose(2 * np.arctan2(q[:, 2], q[:, 3]), est[:, 1], atol=ROUNDOFF)  # yaw about z
    assert abs(p[-1, 0] - 0.49) < 0.05  # 1 m/s for 0.49 s, fixes on the same line
    res = run("--out", str(tmp_path / "out2"))
    assert res.exit_code != 0 and "is a ROS bag: give --topics MAPPING.json" in res.output
    topics.write_text(json.dumps({"/odom": {}, "/gps": {}}))
    res = run("--topics", str(topics), "--out", str(tmp_path / "out2"))
    assert res.exit_code != 0 and "'--topics'" in res.output and "expected a topic of the bag" in res.output


def test_a_zero_quaternion_is_named(tmp_path):
    # The test bag's /imu orientation is the identity; a bag whose IMU sends no orientation (all zeros) is refused
    # with the topic, the column and the field when that orientation is mapped.
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    with Writer2(tmp_path / "zero", version=9) as w:
        conn = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        for k in range(2):
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=k, nanosec=0), frame_id="b"),
                orientation=Q(0.0, 0.0, 0.0, 0.0), orientation_covariance=np.zeros(9), angular_velocity=V3(0, 0, 0),
                angular_velocity_covariance=np.zeros(9), linear_acceleration=V3(0, 0, 0),
                linear_acceleration_covariance=np.zeros(9))
            w.write(conn, k * 10**9, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
    with pytest.raises(ValueError, match=r"mapping\['/imu'\]\['columns'\]\['y1'\]: orientation: expected a nonzero "
                                         r"quaternion, got .* at 'orientation'"):
        read_bag(tmp_path / "zero", {"/imu": {"columns": {"u1": "angular_velocity.x", "y1": "orientation.r11"}}},
                 1, 1)
