"""Contracts every layer may import: state layouts (``core/states.py``)."""
