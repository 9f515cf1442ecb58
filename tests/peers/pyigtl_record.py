"""Record every message an OpenIGTLink server sends, decoded by pyigtl (a peer no one here wrote).

Usage: pyigtl_record.py HOST PORT OUT.csv [--v2]

pyigtl's client keeps only the latest message per device name, so this reads the socket itself
and hands each message to pyigtl's own decoding (MessageBase.parse_header, create_message,
unpack) and its CRC-64. With --v2 it first sends a message with header version 2 (as an
OpenIGTLink 3 client does), after which a PLUS-like server answers with header version 2 and
metadata. One CSV row per message: type, device, timestamp (s), header version, CRC ok,
TransformStatus metadata, then the 12 matrix values of a TRANSFORM (R11 R21 R31 … TX TY TZ).
Stops when the server closes the connection.
"""
import csv
import socket
import struct
import sys

import pyigtl
from pyigtl.messages import CRC64, MessageBase


def main():
    host, port, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    v2 = "--v2" in sys.argv[4:]
    sock = socket.create_connection((host, port))
    if v2:
        hello = pyigtl.StringMessage("kincal peer test", device_name="Hello")
        hello.header_version = 2
        sock.sendall(hello.pack())
    stream = sock.makefile("rb", buffering=1 << 16)
    print("CONNECTED", flush=True)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["type", "device", "timestamp_s", "version", "crc_ok", "status"] + [f"m{k}" for k in range(12)])
        while True:
            header = stream.read(MessageBase.IGTL_HEADER_SIZE)
            if len(header) < MessageBase.IGTL_HEADER_SIZE:
                break
            fields = MessageBase.parse_header(header)
            body = stream.read(fields["body_size"])
            if len(body) < fields["body_size"]:
                break
            crc_ok = struct.unpack("> Q", header[50:58])[0] == CRC64(body)
            message = MessageBase.create_message(fields["message_type"])
            status, matrix = "", []
            if message is not None:
                message.unpack(fields, body)
                status = message.metadata.get("TransformStatus", "")
                if fields["message_type"] == "TRANSFORM":
                    m = message.matrix
                    matrix = [repr(float(m[r][c])) for c in range(4) for r in range(3)]
            w.writerow([fields["message_type"], fields["device_name"], repr(fields["timestamp"]),
                        fields["header_version"], int(crc_ok), status] + matrix)
    print("CLOSED", flush=True)


if __name__ == "__main__":
    main()
