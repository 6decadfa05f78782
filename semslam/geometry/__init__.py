"""Pure geometry: functions of arrays, no I/O and no SLAM state."""
