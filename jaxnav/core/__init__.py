"""Contracts every layer may import: state layouts (``states.py``), the GPS time scale
(``gpstime.py``), a navigation history (``track.py``) and what the sweep engine needs from a
filter (``ops.py``)."""
