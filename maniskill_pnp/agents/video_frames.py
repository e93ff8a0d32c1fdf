"""Frame helpers shared by the agents' videos: a caption band, and the even sides H.264 needs."""

from __future__ import annotations

import numpy as np


def label(img: np.ndarray, text: str) -> np.ndarray:
    """``img`` with ``text`` on a dark band at the top."""
    import cv2

    out = np.ascontiguousarray(img.copy())
    cv2.rectangle(out, (0, 0), (out.shape[1], 20), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def even_frame(frame: np.ndarray) -> np.ndarray:
    """Crop to even sides (H.264 with yuv420p needs them)."""
    return frame[: frame.shape[0] // 2 * 2, : frame.shape[1] // 2 * 2]
