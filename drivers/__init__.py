"""Device drivers behind small interfaces: ``Axis``, ``Lamp`` and ``Camera``.

Real protocols: Dynamixel Protocol 2.0 (dynamixel-sdk), Modbus TCP/RTU (pymodbus), Newport
SMC100 ASCII (pyserial), RAW camera files (rawpy). Only this package and ``sim`` import them.
"""
