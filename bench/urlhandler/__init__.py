"""pyserial URL handlers of the bench: ``usb://`` reads a USB endpoint with pyusb.

Importing this package registers it in ``serial.protocol_handler_packages``, after
which any pyserial client can ``serial.serial_for_url("usb://10c4:ea60?serial=0001")``.
"""

import serial

if __name__ not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(__name__)
