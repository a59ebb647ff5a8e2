"""An explicit modified-DH product, written out independently of vtestbed.transforms."""

import numpy as np

# Paper Table 1 (decoded; models/kuka_kr60_3/README.md): alpha_{i-1} [deg], a_{i-1} [mm], d_i [mm].
TABLE_1 = [(0, 0, 815), (-90, 350, 0), (0, 850, 0), (-90, 145, 820), (90, 0, 0), (-90, 0, 170)]


def link(alpha_deg, a_mm, theta, d_mm):
    al = np.radians(alpha_deg)
    rx = np.array(
        [[1, 0, 0, 0], [0, np.cos(al), -np.sin(al), 0], [0, np.sin(al), np.cos(al), 0], [0, 0, 0, 1.0]]
    )
    tx = np.eye(4)
    tx[0, 3] = a_mm / 1000.0
    rz = np.array(
        [
            [np.cos(theta), -np.sin(theta), 0, 0],
            [np.sin(theta), np.cos(theta), 0, 0],
            [0, 0, 1, 0],
            [0, 0, 0, 1.0],
        ]
    )
    tz = np.eye(4)
    tz[2, 3] = d_mm / 1000.0
    return rx @ tx @ rz @ tz


def flange_pose(q):
    out = np.eye(4)
    for (alpha, a, d), theta in zip(TABLE_1, q):
        out = out @ link(alpha, a, theta, d)
    return out
