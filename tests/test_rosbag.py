"""ROS bag import: ROS 1 and ROS 2 (MCAP and sqlite3) bags written here with rosbags' writers, with
MAVROS topics and PX4 uXRCE-DDS (px4_msgs) topics, read back through load_flight_file."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from scart_bench.cli.main import main  # noqa: E402
from scart_bench.dataset import DatasetError, open_dataset  # noqa: E402
from scart_bench.generator.logs.importers import load_flight_file  # noqa: E402

T0 = 1_700_000_000_000_000_000  # ns
# px4_msgs/msg/SensorGps as PX4 v1.14 defines it (the fields used here)
SENSOR_GPS = """uint64 timestamp
uint64 timestamp_sample
float64 latitude_deg
float64 longitude_deg
float64 altitude_msl_m
float32 vel_n_m_s
float32 vel_e_m_s
float32 vel_d_m_s
uint8 fix_type
"""
VEHICLE_ATTITUDE = """uint64 timestamp
uint64 timestamp_sample
float32[4] q
"""


def _typestore(ros1: bool):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(SENSOR_GPS, "px4_msgs/msg/SensorGps"))
    ts.register(get_types_from_msg(VEHICLE_ATTITUDE, "px4_msgs/msg/VehicleAttitude"))
    return ts


def write_bag(path, kind: str, n: int = 50) -> None:
    """A 10 Hz flight: MAVROS position, pose, IMU, battery; px4_msgs GPS and attitude (5 ms later)."""
    ros1 = kind == "ros1"
    ts = _typestore(ros1)
    T = ts.types
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin[kind.upper()])
    topics = {"/mavros/global_position/global": "sensor_msgs/msg/NavSatFix",
              "/mavros/local_position/pose": "geometry_msgs/msg/PoseStamped",
              "/mavros/imu/data": "sensor_msgs/msg/Imu", "/mavros/battery": "sensor_msgs/msg/BatteryState",
              "/fmu/out/vehicle_gps_position": "px4_msgs/msg/SensorGps",
              "/fmu/out/vehicle_attitude": "px4_msgs/msg/VehicleAttitude"}
    with writer:
        conns = {t: writer.add_connection(t, m, typestore=ts) for t, m in topics.items()}
        for k in range(n):
            t = T0 + k * 100_000_000
            hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                           frame_id="map", **({"seq": k} if ros1 else {}))
            v3 = T["geometry_msgs/msg/Vector3"]
            msgs = {
                "/mavros/global_position/global": T["sensor_msgs/msg/NavSatFix"](
                    header=hdr, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                    latitude=47.3977420 + 9e-6 * k, longitude=8.545594, altitude=488.0 + 0.1 * k,
                    position_covariance=np.zeros(9), position_covariance_type=0),
                "/mavros/local_position/pose": T["geometry_msgs/msg/PoseStamped"](
                    header=hdr, pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=0.5, y=0.1 * k, z=0.1 * k),
                        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))),
                "/mavros/imu/data": T["sensor_msgs/msg/Imu"](
                    header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9), angular_velocity=v3(x=0.01, y=0.02, z=0.03),
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=v3(x=0.1, y=0.2, z=9.81),
                    linear_acceleration_covariance=np.zeros(9)),
                "/mavros/battery": _battery(T, hdr, ros1, 1.0 - 0.001 * k),
                "/fmu/out/vehicle_gps_position": T["px4_msgs/msg/SensorGps"](
                    timestamp=k, timestamp_sample=k, latitude_deg=47.3977420 + 9e-6 * k, longitude_deg=8.545594,
                    altitude_msl_m=488.0, vel_n_m_s=1.0, vel_e_m_s=0.0, vel_d_m_s=0.0, fix_type=3),
                "/fmu/out/vehicle_attitude": T["px4_msgs/msg/VehicleAttitude"](
                    timestamp=k, timestamp_sample=k, q=np.array([1.0, 0.0, 0.0, 0.0], np.float32)),
            }
            for j, (topic, msg) in enumerate(msgs.items()):
                writer.write(conns[topic], t + j * 1_000_000, ser(msg, topics[topic]))


def _battery(T, hdr, ros1: bool, remaining: float):
    B = T["sensor_msgs/msg/BatteryState"]
    args = dict(header=hdr, voltage=16.0, current=-12.0, charge=float("nan"), capacity=float("nan"),
                design_capacity=float("nan"), percentage=remaining, power_supply_status=2, power_supply_health=1,
                power_supply_technology=3, present=True, cell_voltage=np.zeros(0, np.float32), location="",
                serial_number="", temperature=float("nan"), cell_temperature=np.zeros(0, np.float32))
    return B(**{k: v for k, v in args.items() if k in B.__dataclass_fields__})


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_bags_import_mavros_and_px4_topics(tmp_path, kind):
    path = tmp_path / ("flight.bag" if kind == "ros1" else "flight")
    write_bag(path, kind)
    t = load_flight_file(path)
    assert sorted(t) == ["battery_status", "global_position_int", "highres_imu", "local_position_ned",
                         "vehicle_attitude", "vehicle_gps_position"]
    gpi = t["global_position_int"]
    assert len(gpi) == 50 and gpi["Timestamp"].iloc[:2].tolist() == [0, 100_000]  # time zero: the bag's start
    assert gpi.attrs["origin_us"] == T0 // 1000 and gpi.attrs["ros_topic"] == "/mavros/global_position/global"
    assert list(gpi.columns) == ["Timestamp", "lat", "lon", "alt"] and gpi["lat"].iloc[0] == 47.397742
    lpn = t["local_position_ned"]  # ENU -> NED
    assert lpn["Timestamp"].iloc[0] == 1000 and lpn["x"].iloc[10] == pytest.approx(1.0)
    assert lpn["y"].iloc[10] == 0.5 and lpn["z"].iloc[10] == pytest.approx(-1.0)
    imu = t["highres_imu"]  # FLU -> FRD: z about -9.81 at rest, as the generator's highres_imu
    assert imu["zacc"].iloc[0] == pytest.approx(-9.81) and imu["yacc"].iloc[0] == pytest.approx(-0.2)
    assert imu["ygyro"].iloc[0] == pytest.approx(-0.02)
    assert t["battery_status"]["remaining"].iloc[1] == pytest.approx(0.999)
    gps = t["vehicle_gps_position"]  # uORB name and fields, as in a ULog; timestamp is not a column
    assert "timestamp" not in gps.columns and gps["latitude_deg"].iloc[0] == 47.397742 and gps["fix_type"].iloc[0] == 3
    assert t["vehicle_attitude"].columns.tolist() == ["Timestamp", "timestamp_sample", "q_0", "q_1", "q_2", "q_3"]
    part = load_flight_file(path, topics=["vehicle_gps_position"])
    assert part["vehicle_gps_position"]["Timestamp"].equals(gps["Timestamp"])
    with pytest.raises(DatasetError, match=r"topic\(s\) \['sensor_gps'\] not found in the bag; it has: .*"
                       r"'vehicle_gps_position'"):
        load_flight_file(path, topics=["sensor_gps"])


def test_ros2_storage_file_and_errors(tmp_path):
    path = tmp_path / "flight"
    write_bag(path, "mcap", n=10)
    mcap = next(path.glob("*.mcap"))
    assert len(load_flight_file(mcap)["global_position_int"]) == 10  # the file in its bag folder
    lone = tmp_path / "lone.mcap"
    lone.write_bytes(mcap.read_bytes())
    with pytest.raises(DatasetError, match="lone.mcap: a ROS 2 bag is read from its folder, which holds metadata.yaml"):
        load_flight_file(lone)
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag" * 20)
    with pytest.raises(DatasetError, match="junk.bag: not a readable ROS bag"):
        load_flight_file(junk)


def test_bag_cli_import_and_attack(tmp_path, capsys):
    bag = tmp_path / "mavros_flight.bag"
    write_bag(bag, "ros1", n=200)
    ds = tmp_path / "mine"
    assert main(["import", str(bag), "--out", str(ds), "--split", "test"]) == 0
    # a scenario by meaning applies to the mapped topics (altitude: local z above 5 m, after 5 s)
    assert main(["attack", "--dataset", str(ds), "--scenario", "data/scenarios/sensor_gps_jump.toml"]) == 0, \
        capsys.readouterr().err
    assert sorted(open_dataset(ds).manifest["mode"]) == ["csv", "normal"]
