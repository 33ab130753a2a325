"""The CAN bus of a run: its signals, the DBC codec, frame timing, the transport, clients and monitors."""
