"""Rerun recordings: the recording and its file handling (:mod:`.recording`), the series made from
the signal table and the default layout (:mod:`.series`), and the 3-D scene of a MuJoCo model
(:mod:`.scene`). rerun itself is imported only when a recording is opened."""

from .recording import Recording, temporary_path, time_nanoseconds
from .series import TIMELINE, default_blueprint

__all__ = ["TIMELINE", "Recording", "default_blueprint", "temporary_path", "time_nanoseconds"]
