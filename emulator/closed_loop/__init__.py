"""Closed loop: the receiver riding a vehicle (paper eq. 9) steered by a search controller,
or the pose of a real autopilot over MAVLink; the paper case study and seeded sweeps."""
