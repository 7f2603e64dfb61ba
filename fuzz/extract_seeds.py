#!/usr/bin/env python3
"""Extracts fuzz seeds from the shared real-device data (never copied into the project).

extract_seeds.py KIND SHARED_DATA_DIR OUT_DIR
  frame:   every EtherCAT frame (EtherType 0x88A4 or UDP port 34980) of every capture
  mailbox: the data of every FPRD/FPWR datagram of 6 bytes or more in those frames (mailbox
           buffers among them)
  sii:     every EEPROM image
  ring_devices: rings that build devices from every EEPROM image (profile eeprom, alone, without
           firmware, in pairs) and every ESI file (profile esi, alone and beside an image), in
           fuzz_ring_devices' input format: YAML, then the files, each after the separator "\0\0FZ"
           (a.bin, b.bin, c.xml, d.xml in that order)
  master_config: nothing (the shared data holds no master configurations)
"""
import os
import struct
import sys


def pcap_packets(data):
    """Yields (linktype, packet) from a pcap or pcapng file."""
    if len(data) < 24:
        return
    magic = data[:4]
    if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\xa1\xb2\x3c\x4d"):
        endian = "<" if magic in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
        linktype = struct.unpack(endian + "I", data[20:24])[0]
        off = 24
        while off + 16 <= len(data):
            incl = struct.unpack(endian + "I", data[off + 8:off + 12])[0]
            yield linktype, data[off + 16:off + 16 + incl]
            off += 16 + incl
        return
    if magic != b"\x0a\x0d\x0d\x0a":
        return
    off = 0
    endian = "<"
    linktypes = []
    while off + 12 <= len(data):
        btype = struct.unpack(endian + "I", data[off:off + 4])[0]
        if btype == 0x0A0D0D0A:
            bom = data[off + 8:off + 12]
            endian = "<" if bom == b"\x4d\x3c\x2b\x1a" else ">"
            linktypes = []
        blen = struct.unpack(endian + "I", data[off + 4:off + 8])[0]
        if blen < 12 or off + blen > len(data):
            return
        body = data[off + 8:off + blen - 4]
        if btype == 1:
            linktypes.append(struct.unpack(endian + "H", body[0:2])[0])
        elif btype == 6 and len(body) >= 20:
            iface, _, _, caplen, _ = struct.unpack(endian + "IIIII", body[:20])
            lt = linktypes[iface] if iface < len(linktypes) else 1
            yield lt, body[20:20 + caplen]
        elif btype == 3 and len(body) >= 4:
            yield (linktypes[0] if linktypes else 1), body[4:]
        off += blen


def ethercat_payload(linktype, pkt):
    if linktype != 1 or len(pkt) < 14:
        return None
    off = 12
    etype = struct.unpack(">H", pkt[off:off + 2])[0]
    if etype == 0x8100 and len(pkt) >= 18:
        off += 4
        etype = struct.unpack(">H", pkt[off:off + 2])[0]
    if etype == 0x88A4:
        return pkt[off + 2:]
    if etype == 0x0800 and len(pkt) >= off + 2 + 28:
        ip = pkt[off + 2:]
        ihl = (ip[0] & 0x0F) * 4
        if ip[9] == 17 and len(ip) >= ihl + 8:
            dport = struct.unpack(">H", ip[ihl + 2:ihl + 4])[0]
            sport = struct.unpack(">H", ip[ihl:ihl + 2])[0]
            if 0x88A4 in (dport, sport):
                return ip[ihl + 8:]
    return None


def datagrams(frame):
    if len(frame) < 2:
        return
    off = 2
    while off + 12 <= len(frame):
        cmd = frame[off]
        lenf = struct.unpack("<H", frame[off + 6:off + 8])[0]
        n = lenf & 0x7FF
        if off + 12 + n > len(frame):
            return
        yield cmd, frame[off + 10:off + 10 + n]
        off += 12 + n
        if not lenf & 0x8000:
            return


RING_SEPARATOR = b"\0\0FZ"


def ring_input(yaml, *files):
    """fuzz_ring_devices' input: the YAML, then each file after the separator."""
    blob = yaml.encode()
    for f in files:
        blob += RING_SEPARATOR + f
    return blob


def ring_devices_seeds(shared):
    images = []
    d = os.path.join(shared, "eeprom")
    for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
        with open(os.path.join(d, name), "rb") as f:
            images.append(f.read())
    esis = []
    d = os.path.join(shared, "esi")
    for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
        with open(os.path.join(d, name), "rb") as f:
            esis.append(f.read())
    # A file holding the separator would be split: the last part may hold it, so such a file goes
    # last (d.xml); any other place skips it.
    one = "simulator:\n  slaves:\n    - {name: dev, profile: %s, file: %s%s}\n"
    for image in images:
        if RING_SEPARATOR in image:
            yield ring_input(one % ("eeprom", "d.xml", ""), b"", b"", b"", image)
            continue
        yield ring_input(one % ("eeprom", "a.bin", ""), image)
        yield ring_input(one % ("eeprom", "a.bin", ", options: {firmware: none}"), image)
    pair = ("simulator:\n  slaves:\n    - {name: coupler, profile: EK1100}\n"
            "    - {name: first, profile: eeprom, file: a.bin, parent: coupler, port: 3}\n"
            "    - {name: second, profile: eeprom, file: b.bin}\n")
    clean = [i for i in images if RING_SEPARATOR not in i]
    for a, b in zip(clean, clean[1:] + clean[:1]):
        yield ring_input(pair, a, b)
    for esi in esis:
        yield ring_input(one % ("esi", "d.xml", ""), b"", b"", b"", esi)
        if clean:
            yield ring_input("simulator:\n  slaves:\n"
                             "    - {name: io, profile: eeprom, file: a.bin}\n"
                             "    - {name: drive, profile: esi, file: d.xml, clock: {drift_ppm: 20}}\n",
                             clean[0], b"", b"", esi)


def main():
    kind, shared, out = sys.argv[1], sys.argv[2], sys.argv[3]
    os.makedirs(out, exist_ok=True)
    count = 0
    seen = set()

    def emit(blob):
        nonlocal count
        if blob in seen or len(seen) >= 1500:
            return
        seen.add(blob)
        with open(os.path.join(out, "shared-%05d" % count), "wb") as f:
            f.write(blob)
        count += 1

    if kind == "esi":
        d = os.path.join(shared, "esi")
        for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
            with open(os.path.join(d, name), "rb") as f:
                emit(f.read())
    elif kind == "sii":
        d = os.path.join(shared, "eeprom")
        for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
            with open(os.path.join(d, name), "rb") as f:
                emit(f.read())
    elif kind == "ring_devices":
        for blob in ring_devices_seeds(shared):
            emit(blob)
    elif kind in ("frame", "mailbox"):
        d = os.path.join(shared, "captures")
        for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
            with open(os.path.join(d, name), "rb") as f:
                data = f.read()
            for lt, pkt in pcap_packets(data):
                frame = ethercat_payload(lt, pkt)
                if frame is None:
                    continue
                if kind == "frame":
                    emit(bytes(frame))
                elif kind == "mailbox":
                    for cmd, payload in datagrams(frame):
                        if cmd in (4, 5) and len(payload) >= 6:
                            emit(bytes(payload))
    print("extracted %d %s seeds from %s" % (count, kind, shared))


if __name__ == "__main__":
    main()
