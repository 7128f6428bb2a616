"""The coarse plan's walls as a reference for a frame placed by the track (thesis 3.2.2.6, and beyond it):
the frame's Hough lines matched to the plan walls to correct its heading (and shift it onto the wall
faces), and a 2D point-to-line ICP of its wall points onto the walls' faces."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from tasks.lines import angle_difference, angles
from tasks.register.config import RegisterConfig
from tasks.register.fusion import transform_points


def wall_lines(points_plan: NDArray[np.float64], cfg: RegisterConfig) -> NDArray[np.float64]:
    """(L, 4) Hough lines x0 y0 x1 y1 (plan metres) of one placed frame (3.2.2.6): its wall-band points
    projected onto the floor into a count image, binarised, closed, skeletonised, probabilistic Hough."""
    import cv2
    from skimage.morphology import skeletonize

    lo, hi = cfg.wall_band_m
    p = points_plan[(points_plan[:, 2] > lo) & (points_plan[:, 2] < hi)]
    if len(p) < 50:
        return np.zeros((0, 4))
    cell = cfg.line_cell_m
    origin = p[:, :2].min(axis=0) - 2 * cell
    ij = np.floor((p[:, :2] - origin) / cell).astype(np.intp)
    w, h = ij.max(axis=0) + 3
    if w * h > 4e6:
        return np.zeros((0, 4))
    img = np.zeros((h, w), np.int32)
    np.add.at(img, (ij[:, 1], ij[:, 0]), 1)
    binary = (img >= cfg.line_min_count).astype(np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    skel = skeletonize(binary > 0).astype(np.uint8) * 255
    min_len = max(int(cfg.line_min_length_m / cell), 5)
    lines = cv2.HoughLinesP(
        skel, 1, np.pi / 360, threshold=max(min_len // 2, 5), minLineLength=min_len, maxLineGap=5
    )
    if lines is None:
        return np.zeros((0, 4))
    seg = (lines.reshape(-1, 4).astype(np.float64) + 0.5) * cell  # cell centres
    seg[:, [0, 2]] += origin[0]
    seg[:, [1, 3]] += origin[1]
    return seg


def _point_segment_distances(p: NDArray[np.float64], walls: NDArray[np.float64]) -> NDArray[np.float64]:
    """(L, M) distances of (L, 2) points to (M, 4) segments."""
    # not tasks.lines.point_segment_distances: that one projects with a normalised parameter and differs in
    # the last bits (up to 4e-15 m), which can flip a tie in the wall matching and move a placement
    a, b = walls[:, :2], walls[:, 2:4]
    d = b - a
    ln = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    u = d / ln[:, None]
    rel = p[:, None, :] - a[None]
    along = np.clip((rel * u[None]).sum(axis=2), 0, ln[None])
    closest = a[None] + along[..., None] * u[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2)


def _weighted_median(values: NDArray[np.float64], weights: NDArray[np.float64]) -> float:
    order = np.argsort(values)
    cw = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


def match_plan_lines(
    lines: NDArray[np.float64], plan_walls: NDArray[np.float64], max_angle_rad: float, max_distance_m: float
) -> tuple[NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
    """For each frame line the corresponding plan wall (3.2.2.6): among the walls of similar orientation
    (within `max_angle_rad`) whose face lies within `max_distance_m` of the line's midpoint, the closest,
    orientation breaking ties. Returns ((L,) wall index, (L,) signed orientation difference line - wall,
    (L,) matched)."""
    mids = 0.5 * (lines[:, :2] + lines[:, 2:4])
    dist = _point_segment_distances(mids, plan_walls[:, :4])
    face_dist = np.maximum(dist - 0.5 * _thickness(plan_walls)[None], 0.0)
    dang = angle_difference(angles(lines)[:, None], angles(plan_walls[:, :4])[None])
    ok = (np.abs(dang) <= max_angle_rad) & (face_dist <= max_distance_m)
    score = np.where(ok, face_dist + 0.5 * np.abs(dang), np.inf)
    best = np.argmin(score, axis=1)
    rows = np.arange(len(lines))
    return best, dang[rows, best], np.isfinite(score[rows, best])


def plan_line_correction(
    lines: NDArray[np.float64],
    plan_walls: NDArray[np.float64],
    cfg: RegisterConfig,
    tolerance: float = 1.0,
    centre: NDArray[np.float64] | None = None,
) -> tuple[float, NDArray[np.float64], int]:
    """Heading correction (3.2.2.6): each frame line is matched to its plan wall (`match_plan_lines`); the
    length-weighted median orientation difference is the correction (radians, to subtract; the thesis takes
    the mean, the median ignores lines of furniture that match no wall). `tolerance` scales the matching
    tolerances (`line_max_angle_deg`, `line_max_distance_m`): 1 for the first pass, smaller later. With
    `line_fix_offset` and wall thickness given (column 4), the frame's shift across the matched wall faces is
    also returned (after the heading fix about `centre`, the camera's xy; robust least squares over the
    lines, (2,) metres to add).
    Returns (angle, shift, matched lines)."""
    if len(lines) == 0 or len(plan_walls) == 0:
        return 0.0, np.zeros(2), 0
    f = tolerance
    best, dang, matched = match_plan_lines(
        lines, plan_walls, np.radians(cfg.line_max_angle_deg) * f, cfg.line_max_distance_m * f
    )
    if not matched.any():
        return 0.0, np.zeros(2), 0
    w = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])[matched]
    angle = _weighted_median(dang[matched], w)
    shift = np.zeros(2)
    if cfg.line_fix_offset and tolerance < 1.0 and plan_walls.shape[1] >= 5:
        c0 = np.zeros(2) if centre is None else np.asarray(centre, dtype=np.float64)[:2]
        ca, sa = np.cos(-angle), np.sin(-angle)
        rot = np.array([[ca, -sa], [sa, ca]])
        mids = (0.5 * (lines[:, :2] + lines[:, 2:4]) - c0) @ rot.T + c0
        A, rhs, ww = [], [], []
        for k in np.flatnonzero(matched):
            wall = plan_walls[best[k]]
            d = wall[2:4] - wall[:2]
            u = d / max(np.linalg.norm(d), 1e-9)
            nrm = np.array([-u[1], u[0]])
            off = float((mids[k] - wall[:2]) @ nrm)
            # the camera sees the face on its own side of the wall
            face = np.sign(float((c0 - wall[:2]) @ nrm)) * 0.5 * wall[4]
            A.append(nrm)
            rhs.append(face - off)
            ww.append(np.hypot(*(lines[k, 2:4] - lines[k, :2])))
        A_arr, r_arr, w_arr = np.array(A), np.array(rhs), np.array(ww)
        for _ in range(5):  # iteratively reweighted: lines of furniture near a wall must not pull the frame
            sw = np.sqrt(w_arr)
            shift, *_ = np.linalg.lstsq(A_arr * sw[:, None], r_arr * sw, rcond=None)
            res = np.abs(A_arr @ shift - r_arr)
            w_arr = np.array(ww) / np.maximum(res / 0.03, 1.0)
    return angle, shift, int(matched.sum())


def _thickness(plan_walls: NDArray[np.float64]) -> NDArray[np.float64]:
    return plan_walls[:, 4] if plan_walls.shape[1] >= 5 else np.zeros(len(plan_walls))


class PlanFit(NamedTuple):
    """One frame fitted to the plan walls by `fit_to_plan`."""

    T: NDArray[np.float64]
    """Corrected depth camera → plan (4, 4)."""
    angle: float
    """Total heading correction (rad)."""
    score: float
    """Agreement: the length (m) of the frame's lines lying on a plan wall face within 5 cm and 2 degrees."""
    length: float
    """The length (m) of all the frame's lines."""
    information: NDArray[np.float64]
    """(2, 2) sum over the agreeing lines of length x n n^T (n: the matched wall's normal): the directions in
    which the walls pin the frame's position (rank 1 for a frame seeing one corridor's walls only)."""


def fit_to_plan(
    T: NDArray[np.float64],
    points_cam: NDArray,
    plan_walls: NDArray[np.float64],
    cfg: RegisterConfig,
    tolerances: tuple[float, ...] = (1.0, 0.5, 0.25, 0.25),
) -> PlanFit:
    """Passes of `plan_line_correction` with the given (shrinking) tolerances on one frame placed at T
    (depth camera → plan): the heading turned about the camera and, when thickness is given, the frame
    shifted onto the wall faces."""
    pts = transform_points(T, np.asarray(points_cam, dtype=np.float64))
    total = 0.0
    for tolerance in tolerances:
        angle, shift, n = plan_line_correction(wall_lines(pts, cfg), plan_walls, cfg, tolerance, T[:2, 3])
        if n == 0:
            continue
        c, s = np.cos(-angle), np.sin(-angle)
        Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        centre = T[:3, 3].copy()
        D = np.eye(4)
        D[:3, :3] = Rz
        D[:3, 3] = centre - Rz @ centre
        D[:2, 3] += shift
        T = D @ T
        pts = transform_points(D, pts)
        total -= angle
    lines = wall_lines(pts, cfg)
    score = length = 0.0
    info = np.zeros((2, 2))
    if len(lines):
        best, _dang, ok = match_plan_lines(lines, plan_walls, np.radians(2.0), 0.05)
        seg_len = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
        score, length = float(seg_len[ok].sum()), float(seg_len.sum())
        a = angles(plan_walls[best[ok], :4])
        nrm = np.column_stack([-np.sin(a), np.cos(a)])
        info = (nrm * seg_len[ok, None]).T @ nrm
    return PlanFit(T, total, score, length, info)


def plan_faces(plan_walls: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The surfaces a sensor sees of the plan walls ((M, 4) centrelines, or (M, 5) with thickness): both faces
    of each wall, thickness/2 either side of its centreline, and its two end faces (door jambs, wall ends).
    Returns ((F, 4) face segments x0 y0 x1 y1, (F, 2) unit normals pointing out of the wall, to the side
    from which the face can be seen)."""
    walls = np.asarray(plan_walls, dtype=np.float64)
    a, b = walls[:, :2], walls[:, 2:4]
    ln = np.linalg.norm(b - a, axis=1)
    keep = ln > 1e-6
    a, b, ln, half = a[keep], b[keep], ln[keep], 0.5 * _thickness(walls)[keep]
    u = (b - a) / ln[:, None]
    n = np.column_stack([-u[:, 1], u[:, 0]])
    off = n * half[:, None]
    segs = [np.hstack([a + off, b + off]), np.hstack([a - off, b - off])]
    normals = [n, -n]
    thick = half > 1e-3
    if thick.any():  # end faces
        segs += [np.hstack([a - off, a + off])[thick], np.hstack([b - off, b + off])[thick]]
        normals += [-u[thick], u[thick]]
    return np.vstack(segs), np.vstack(normals)


def _nearest_faces(
    p: NDArray[np.float64],
    faces: NDArray[np.float64],
    normals: NDArray[np.float64],
    max_distance_m: float,
    viewpoint: NDArray[np.float64],
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """For (N, 2) points, the face each lies nearest among those facing `viewpoint` (within
    `max_distance_m`, its foot on the face) and the signed distance along the face normal; -1 and NaN where
    none. Only the faces turned toward the sensor count: a wall's far face is a thickness away from its near
    one, nearer than a frame's error may be."""
    lo = p.min(axis=0) - max_distance_m
    hi = p.max(axis=0) + max_distance_m
    near = np.flatnonzero(
        (((viewpoint - faces[:, :2]) * normals).sum(axis=1) > 0)
        & (np.minimum(faces[:, 0], faces[:, 2]) <= hi[0])
        & (np.maximum(faces[:, 0], faces[:, 2]) >= lo[0])
        & (np.minimum(faces[:, 1], faces[:, 3]) <= hi[1])
        & (np.maximum(faces[:, 1], faces[:, 3]) >= lo[1])
    )
    idx = np.full(len(p), -1, dtype=np.intp)
    signed = np.full(len(p), np.nan)
    if len(near) == 0 or len(p) == 0:
        return idx, signed
    f, nf = faces[near], normals[near]
    a, d = f[:, :2], f[:, 2:4] - f[:, :2]
    ln = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    u = d / ln[:, None]
    rel = p[:, None, :] - a[None]
    along = (rel * u[None]).sum(axis=2)
    across = (rel * nf[None]).sum(axis=2)
    on = (along >= -0.02) & (along <= ln[None] + 0.02) & (np.abs(across) <= max_distance_m)
    dist = np.where(on, np.abs(across), np.inf)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(p))
    ok = np.isfinite(dist[rows, best])
    idx[ok] = near[best[ok]]
    signed[ok] = across[rows, best][ok]
    return idx, signed


def icp_to_plan(
    T: NDArray[np.float64],
    points_cam: NDArray,
    faces: tuple[NDArray[np.float64], NDArray[np.float64]],
    cfg: RegisterConfig,
    reach_m: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int, int]:
    """2D point-to-line ICP of one frame's wall-band points (thinned to one per `line_cell_m` cell) onto the
    plan's wall faces (`plan_faces`, end faces included): heading about the camera and position, with the
    correspondence distance shrinking from `reach_m` (default `track_refit_max_shift_m`) to 5 cm and robust (Cauchy) weights.
    Returns (corrected T, (2, 2) information: sum over the matched points of n n^T, matched points, points)."""
    face_segs, normals = faces
    lo, hi = cfg.wall_band_m
    pts = transform_points(T, np.asarray(points_cam, dtype=np.float64))
    pts = pts[(pts[:, 2] > lo) & (pts[:, 2] < hi), :2]
    info = np.zeros((2, 2))
    if len(pts) == 0 or len(face_segs) == 0:
        return T, info, 0, 0
    _, first = np.unique(np.floor(pts / cfg.line_cell_m).astype(np.int64), axis=0, return_index=True)
    p = pts[first]
    c = T[:2, 3].copy()
    R = np.eye(2)
    t = np.zeros(2)
    matched = 0
    for max_d in np.geomspace(max(reach_m or cfg.track_refit_max_shift_m, 0.05), 0.05, 8):
        q = (p - c) @ R.T + c + t
        idx, signed = _nearest_faces(q, face_segs, normals, float(max_d), c + t)
        ok = idx >= 0
        matched = int(ok.sum())
        if matched < 10:
            break
        n = normals[idx[ok]]
        r = signed[ok]
        arm = q[ok] - (c + t)
        J = np.column_stack([n[:, 1] * arm[:, 0] - n[:, 0] * arm[:, 1], n])  # d(n.q)/d(yaw, tx, ty)
        w = 1.0 / (1.0 + (r / 0.03) ** 2)
        sw = np.sqrt(w)
        delta, *_ = np.linalg.lstsq(J * sw[:, None], -r * sw, rcond=None)
        ca, sa = np.cos(delta[0]), np.sin(delta[0])
        dR = np.array([[ca, -sa], [sa, ca]])
        R = dR @ R
        t = t + delta[1:]
        info = (n * w[:, None]).T @ n
    D = np.eye(4)
    D[:2, :2] = R
    D[:2, 3] = c + t - R @ c
    return D @ T, info, matched, len(p)
