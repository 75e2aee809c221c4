"""Runtime: the payload sensor on a CAN bus (J1939), log replay and recording, C and ONNX export."""
