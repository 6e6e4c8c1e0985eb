"""Async transport drivers and wire codecs (installed as ins_hil.drivers)."""
