"""Interoperability with the tools robot people already use.

* :mod:`.messages` — run data as Foxglove messages: the topics (one table, :data:`TOPICS`),
  telemetry rows as JSON, poses and transforms as Foxglove's well-known protobuf schemas
  (taken from ``foxglove-sdk``, never written here);
* :mod:`.mcap_export` — ``ddrobot export RUN_DIR [--report OUT_DIR] --out FILE.mcap``;
* :mod:`.rosbag_import` — ``ddrobot import BAG --map MAP --out RUN_DIR`` (ROS 1 bags, ROS 2
  sqlite3 and MCAP bags through ``rosbags``);
* :mod:`.live` — a Foxglove WebSocket server that the logger (``log --live``) and
  ``fil record --live`` hand each decoded telemetry row to.
"""
