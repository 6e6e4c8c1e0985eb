"""Real-time runtime: asyncio loop, metrics, publishers (MAVLink, MQTT), recorder, exact replay.

``Gateway`` (loop) runs a validated config; ``RuntimeMetrics`` is the API the
status view, MQTT health and soak tests read; ``replay_log`` reruns a
recorder log offline and reproduces the online states exactly.
"""
