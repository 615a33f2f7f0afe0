"""A stand-in for ``gphoto2`` as the README's recipe calls it: set the shutter speed by its label,
capture, and download the RAW file into the folder of ``--filename`` (a DNG whose EXIF
ExposureTime is the exposure taken).

``gphoto2 --set-config shutterspeed=LABEL --capture-image-and-download --filename PATTERN``;
PATTERN's %Y %m %d %H %M %S %n %C are gphoto2's (date, time, number, suffix). What the camera
does beyond that comes from the environment: STANDIN_EXPOSURE_S (it takes this exposure whatever
the label says), STANDIN_REPEAT=1 (it downloads the previous picture again, under a new name).
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from calib.config import shutter_seconds
from drivers.dng import write_dng


def main(argv) -> int:
    parser = argparse.ArgumentParser(prog="gphoto2")
    parser.add_argument("--set-config", action="append", default=[])
    parser.add_argument("--capture-image-and-download", action="store_true")
    parser.add_argument("--filename", required=True)
    args = parser.parse_args(argv)
    config = dict(item.split("=", 1) for item in args.set_config)
    seconds = shutter_seconds(config.get("shutterspeed"))
    if seconds is None or not args.capture_image_and_download:
        print(f"*** Error: bad shutterspeed {config.get('shutterspeed')!r} or no capture", file=sys.stderr)
        return 1
    seconds = float(os.environ.get("STANDIN_EXPOSURE_S", seconds))
    folder = Path(args.filename).parent
    counter = folder / ".standin-count"   # no RAW suffix: the watched folder ignores it
    number = int(counter.read_text()) + 1 if counter.exists() else 1
    counter.write_text(str(number))
    stamp = time.strftime("%Y%m%d%H%M%S")
    name = args.filename
    for key, value in (("%Y", stamp[:4]), ("%m", stamp[4:6]), ("%d", stamp[6:8]), ("%H", stamp[8:10]),
                       ("%M", stamp[10:12]), ("%S", stamp[12:14]), ("%n", f"{number:04d}"), ("%C", "dng")):
        name = name.replace(key, value)
    last = folder / ".standin-last"
    if os.environ.get("STANDIN_REPEAT") and last.exists():
        shutil.copyfile(last, name)
        return 0
    mosaic = np.full((64, 64), 512 + int(1000 * seconds) % 4000, dtype=np.uint16)
    write_dng(Path(name), mosaic, 512, 16383, {"exposure_s": seconds, "label": config["shutterspeed"]},
              model="Stand-in DSLR", make="Stand-in")
    shutil.copyfile(name, last)
    print(f"Saving file as {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
