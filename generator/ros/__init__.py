"""SCART inside ROS: the attack layer as a node on MAVROS topics, a MAVROS stand-in and a mission computer.

The ROS-free part (what a ROS 2 transport reuses as is):

- :mod:`scart_bench.generator.ros.topics`: the MAVROS topics as dataset topics (names, message types,
  fields in MAVROS's frames and units: ENU, FLU, metres, degrees, tesla, pascal), with the field
  paths inside each message;
- :mod:`scart_bench.generator.ros.layer`: :class:`~scart_bench.generator.ros.layer.RosLayer`, the SCART
  layer on one message at a time (clock from the header stamps, both views, labels, the recording);
- :mod:`scart_bench.generator.ros.mission`: the mission computer's square, flown by velocity setpoints
  from the position it perceives.

The ROS 1 transport (:mod:`scart_bench.generator.ros.ros1`) is the only module that imports rospy and
the message packages: the SCART node, the MAVROS stand-in and the navigator node.
"""

from __future__ import annotations

import sys
from pathlib import Path

from scart_bench.errors import ScartBenchError

#: Where Debian's ROS 1 packages (python3-rospy, python3-sensor-msgs ...) install their Python modules.
DEBIAN_ROS_PATH = Path("/usr/lib/python3/dist-packages")
INSTALL_HINT = (
    "apt-get install -y --no-install-recommends ros-core python3-rospy python3-sensor-msgs "
    "python3-geometry-msgs python3-nav-msgs"
)


class RosError(ScartBenchError):
    """ROS is missing, or a node cannot be set up as asked."""


def require_rospy():
    """The ``rospy`` module. When this Python (a virtual environment) cannot import it but Debian's ROS 1
    packages are installed, their folder is appended to ``sys.path`` (after everything else, so the
    environment's own packages win); otherwise a RosError says what to install."""
    try:
        import rospy
    except ImportError:
        if (DEBIAN_ROS_PATH / "rospy").is_dir() and str(DEBIAN_ROS_PATH) not in sys.path:
            sys.path.append(str(DEBIAN_ROS_PATH))
            try:
                import rospy
            except ImportError as exc:
                raise RosError(
                    f"rospy is installed in {DEBIAN_ROS_PATH} but cannot be imported here ({exc}); "
                    "run with the Python it was built for (Debian's python3)"
                ) from exc
        else:
            raise RosError(
                f"the ROS node needs ROS 1 (rospy), which is not installed: {INSTALL_HINT}"
            ) from None
    return rospy
