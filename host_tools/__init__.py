"""Host tools for the slip-avoiding differential-drive robot.

Run ``python -m host_tools --help`` for the list of commands.
"""

__version__ = "0.1.0"
