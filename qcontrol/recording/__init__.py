"""Rerun recordings: the recording (:mod:`.recording`) and its file (:mod:`.rrd_file`), the observer that
streams a run into it (:mod:`.streamer`), the series made from the signal table (:mod:`.series`),
the layout (:mod:`.layout`), the 3-D scene of a MuJoCo model (:mod:`.scene`) and its fixed camera
(:mod:`.camera`). rerun itself is imported only when a recording is opened."""

from .layout import default_blueprint
from .recording import Recording
from .series import TIMELINE
from .streamer import time_nanoseconds

__all__ = ["TIMELINE", "Recording", "default_blueprint", "time_nanoseconds"]
