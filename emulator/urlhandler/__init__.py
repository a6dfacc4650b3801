"""pyserial URL handlers of the emulator: ``arvaemu://`` opens an emulated receiver.

Importing this package registers it in ``serial.protocol_handler_packages``, after
which any pyserial client can ``serial.serial_for_url("arvaemu://scene.toml")``.
"""

import serial

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)
