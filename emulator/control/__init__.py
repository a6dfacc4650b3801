"""The live control channel of ``arva-emulate --control`` (BRIEF 9): requests, the
socket server, the live scene state they change, and the step clock."""
