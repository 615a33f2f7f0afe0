"""Calling dynamixel-sdk the way any client on a busy machine must: repeat a timed-out call."""
from dynamixel_sdk import COMM_RX_TIMEOUT


def sdk_call(call, *args):
    """An SDK call, repeated up to 5 times while its reply timed out: the SDK waits only ~35 ms
    for a status packet, which a loaded 2-core test machine can miss."""
    for _ in range(5):
        out = call(*args)
        if out[-2] != COMM_RX_TIMEOUT:
            return out
    return out
