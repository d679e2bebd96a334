"""Photographs for benchmark 20, as raw RGB files: OUT/photo640.rgb (640x480) and OUT/photo1080.rgb
(1920x1080).

Usage: photos.py OUT. The photographs are scikit-image's bundled sample data (astronaut, coffee, chelsea,
rocket, the Middlebury motorcycle, gravel), taken from the scikit-image wheel: imported when it is
installed, else downloaded once with pip (no dependencies) into OUT and read from the wheel's zip. 640x480
is the motorcycle, cropped at its own resolution; 1920x1080 is a 3x2 mosaic of six photographs, each
brought to 640x540 by area averaging, so the edges per pixel are a photograph's, not an upscale's.
"""

import glob
import os
import subprocess
import sys
import zipfile

import cv2
import numpy as np

NAMES = ["motorcycle_left.png", "astronaut.png", "coffee.png", "chelsea.png", "rocket.jpg", "gravel.png"]


def photographs(out):
    try:
        import skimage

        folder = os.path.join(os.path.dirname(skimage.__file__), "data")
        read = lambda name: open(os.path.join(folder, name), "rb").read()
    except ImportError:
        wheels = glob.glob(os.path.join(out, "scikit_image-*.whl"))
        if not wheels:
            subprocess.run(
                [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "scikit-image", "-d", out],
                check=True,
            )
            wheels = glob.glob(os.path.join(out, "scikit_image-*.whl"))
        wheel = zipfile.ZipFile(wheels[0])
        read = lambda name: wheel.read("skimage/data/" + name)
    decoded = {}
    for name in NAMES:
        bgr = cv2.imdecode(np.frombuffer(read(name), np.uint8), cv2.IMREAD_COLOR)
        decoded[name] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return decoded


def main():
    out = sys.argv[1]
    photos = photographs(out)
    motorcycle = photos["motorcycle_left.png"]
    top, left = (motorcycle.shape[0] - 480) // 2, (motorcycle.shape[1] - 640) // 2
    np.ascontiguousarray(motorcycle[top : top + 480, left : left + 640]).tofile(os.path.join(out, "photo640.rgb"))
    tiles = [cv2.resize(photos[name], (640, 540), interpolation=cv2.INTER_AREA) for name in NAMES]
    mosaic = np.vstack([np.hstack(tiles[:3]), np.hstack(tiles[3:])])
    np.ascontiguousarray(mosaic).tofile(os.path.join(out, "photo1080.rgb"))


main()
