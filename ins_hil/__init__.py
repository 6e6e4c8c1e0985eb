"""ins_hil: hardware-in-the-loop navigation gateway (strapdown INS, EKF, FDI, MAVLink/MQTT)."""

__version__ = "0.1.0"
