"""EGM96 geoid undulation N (m, geoid above the WGS84 ellipsoid) for MSL altitudes: H = h − N.

The grid ``egm96_1deg.bin`` (shipped in the package, no download) holds the EGM96 undulation
at every whole degree, latitude −90…90 (181 rows, south to north) × longitude −180…180
(361 columns, west to east, the last column repeating the first), as little-endian int16
centimetres. The values are the nodes at whole degrees of the complete EGM96 5' grid bundled
by the PyPI package ``egm96`` 0.3.0 (MIT; the NGA EGM96 model), subsampled every 12th node.

Accuracy of the bilinear interpolation of this 1° grid against the full 5' grid (every 5'
node of the globe): RMS 0.48 m (area-weighted), 99 % of the nodes within 1.85 m, worst
13.7 m (steep geoid over the Andes and the Himalaya). EGM96 itself is good to ~0.5–1 m
against the true geoid. Enough for MAVLink's MSL fields (a flight controller's barometer
or its own GNSS MSL height is no better); the ellipsoid height is sent exactly where a
field exists for it (GPS_RAW_INT ``alt_ellipsoid``).
"""

from __future__ import annotations

import math
import sys
from functools import lru_cache
from pathlib import Path

_NLAT, _NLON = 181, 361


@lru_cache(maxsize=1)
def _grid() -> memoryview:
    # the package's data file beside this module (importlib.resources would import tempfile, random, shutil, ...:
    # ~8 ms of every replay that needs a height)
    data = Path(__file__).with_name("egm96_1deg.bin").read_bytes()
    if len(data) != 2 * _NLAT * _NLON:
        raise RuntimeError(f"egm96_1deg.bin: {len(data)} bytes, expected {2 * _NLAT * _NLON}")
    mv = memoryview(bytearray(data)).cast("h")
    if sys.byteorder != "little":  # the file is little endian
        import array

        a = array.array("h", data)
        a.byteswap()
        mv = memoryview(a)
    return mv


def undulation(lat: float, lon: float) -> float:
    """EGM96 geoid height N (m) above the WGS84 ellipsoid at geodetic ``lat``, ``lon`` (rad).

    Bilinear in the 1° grid; longitude wraps, latitude is clamped to ±90°. Scalar floats
    only (≈1 µs): cheap enough for every MAVLink position message."""
    g = _grid()
    fi = min(max(math.degrees(lat) + 90.0, 0.0), 180.0)
    fj = (math.degrees(lon) + 180.0) % 360.0
    i = min(int(fi), _NLAT - 2)
    j = min(int(fj), _NLON - 2)
    a = fi - i
    b = fj - j
    k = i * _NLON + j
    v00, v01 = g[k], g[k + 1]
    v10, v11 = g[k + _NLON], g[k + _NLON + 1]
    return 0.01 * ((1.0 - a) * ((1.0 - b) * v00 + b * v01) + a * ((1.0 - b) * v10 + b * v11))


def msl_height(lat: float, lon: float, h: float) -> float:
    """Height above mean sea level (m, EGM96) of a point at ellipsoidal height ``h`` (m)."""
    return h - undulation(lat, lon)


def ellipsoidal_height(lat: float, lon: float, msl: float) -> float:
    """WGS84 height (m) of a point ``msl`` m above mean sea level (EGM96) at ``lat``, ``lon`` (rad); a non-finite
    position leaves ``msl`` as it is (the validation boundary refuses the sample, not the geoid)."""
    if not (math.isfinite(lat) and math.isfinite(lon)):
        return msl
    return msl + undulation(lat, lon)
