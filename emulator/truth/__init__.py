"""Ground truth the emulator emits beside the receiver: GPS NMEA (GGA + RMC) and $PASHR
attitude writers, and the ground-truth error effect that degrades them."""
