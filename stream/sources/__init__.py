"""Sources: adapters that publish joint, tracker and temperature samples on the bus.

``sim`` (the simulated cell), ``dataset`` (a dataset file as a live cell), ``ros2`` (ROS 2 over
Zenoh, needs ``rosbags``) and ``opcua`` (temperatures, needs ``asyncua``); ``config`` holds their
``[[sources]]`` settings and ``build`` makes and runs them for the daemon. The ROS 2 and OPC UA
modules are imported only where they are used.
"""

from stream.sources._base import Source
from stream.sources.sim import SimCellSource

__all__ = ["SimCellSource", "Source"]
