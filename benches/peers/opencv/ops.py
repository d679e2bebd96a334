"""The OpenCV side of benchmark 20: the same operations on the same raw RGB images, one thread.

Usage: ops.py IMAGE.rgb WIDTH HEIGHT ITERATIONS. Prints one JSON object: operation -> median µs.
"""

import json
import sys
import time

import cv2
import numpy as np


def median_us(operation, iterations):
    for _ in range(5):
        operation()
    times = []
    for _ in range(iterations):
        start = time.perf_counter()
        operation()
        times.append(time.perf_counter() - start)
    times.sort()
    return times[len(times) // 2] * 1e6


def main():
    path, width, height, iterations = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    cv2.setNumThreads(1)
    rgb = np.fromfile(path, dtype=np.uint8).reshape(height, width, 3)
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    operations = {
        "rgb_to_gray": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY),
        "rgb_to_bgr": lambda: cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
        "resize_half_bilinear": lambda: cv2.resize(rgb, (width // 2, height // 2), interpolation=cv2.INTER_LINEAR),
        "resize_0.4_bilinear": lambda: cv2.resize(
            rgb, (round(width * 0.4), round(height * 0.4)), interpolation=cv2.INTER_LINEAR
        ),
        "resize_0.75_bilinear": lambda: cv2.resize(
            rgb, (round(width * 0.75), round(height * 0.75)), interpolation=cv2.INTER_LINEAR
        ),
        "resize_0.4_area": lambda: cv2.resize(rgb, (round(width * 0.4), round(height * 0.4)), interpolation=cv2.INTER_AREA),
        "gaussian_blur_5x5": lambda: cv2.GaussianBlur(rgb, (5, 5), 0),
        "canny": lambda: cv2.Canny(grey, 50, 150),
        "jpeg_encode_q90": lambda: cv2.imencode(".jpg", rgb, [cv2.IMWRITE_JPEG_QUALITY, 90]),
    }
    print(json.dumps({name: median_us(op, iterations) for name, op in operations.items()}))


main()
