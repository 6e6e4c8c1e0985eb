"""The MAVLink messages of the output endpoints, by role: :mod:`.common` (dialect, streams and rates,
framing, HEARTBEAT/SYSTEM_TIME and the vehicle's status), :mod:`.gcs` (to a ground station), :mod:`.fc`
(to a flight controller) and :mod:`.requests` (answers to a ground station). Each role is a mixin of
:class:`~ins_hil.runtime.mavlink_out.MavlinkEndpoint`, which schedules and sends them."""
