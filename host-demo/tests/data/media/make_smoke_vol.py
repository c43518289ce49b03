#!/usr/bin/env python3
"""Writes smoke.vol: a 16^3 one-channel f32 grid (Mitsuba's .vol format) of a lopsided blob of
density (two Gaussians, values in [0, 1]), for smoke.xml / smoke-v06.xml. Run once; committed."""
import math
import os
import struct

N = 16
HERE = os.path.dirname(os.path.abspath(__file__))


def density(x, y, z):
    a = math.exp(-((x - 0.45) ** 2 + (y - 0.4) ** 2 + (z - 0.5) ** 2) / (2 * 0.18 ** 2))
    b = 0.6 * math.exp(-((x - 0.7) ** 2 + (y - 0.7) ** 2 + (z - 0.4) ** 2) / (2 * 0.1 ** 2))
    return min(1.0, a + b)


def main():
    values = []
    for k in range(N):
        for j in range(N):
            for i in range(N):
                values.append(density((i + 0.5) / N, (j + 0.5) / N, (k + 0.5) / N))
    with open(os.path.join(HERE, "smoke.vol"), "wb") as f:
        f.write(b"VOL" + bytes([3]))
        f.write(struct.pack("<5i", 1, N, N, N, 1))
        # The box smoke-v06.xml places the grid on (Mitsuba 0.6 reads it; Mitsuba 3 ignores it).
        f.write(struct.pack("<6f", -0.8, 0.05, -0.8, 0.8, 1.65, 0.8))
        f.write(struct.pack("<%df" % len(values), *values))


if __name__ == "__main__":
    main()
