"""Frames and conventions (BRIEF 2): geodesy (WGS-84 <-> ENU), quaternions and rotations,
the NMEA/$PASHR attitude convention, trajectories, MAVLink NED/FRD <-> ENU/FLU.

The only part of the emulator that ``bench`` needs for frame math; it depends on nothing
else of the emulator."""
