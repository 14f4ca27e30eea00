#!/usr/bin/python3
"""Frame-to-frame tracking with Open3D 0.16, as peers for `fslam track`.

Runs, on the same frames of one RGB-D sequence:
  rgbd  Open3D RGB-D odometry (compute_rgbd_odometry, hybrid photometric + geometric term,
        default OdometryOption: pyramid iterations [20, 10, 5], depth_diff_max 0.03 m,
        depth range 0..4 m), full resolution, each frame against the previous one;
  gicp  Open3D generalized ICP (registration_generalized_icp) on clouds voxel-downsampled to
        2 cm with normals estimated by Open3D (20 nearest neighbours, what its GICP uses when a
        cloud has none), max correspondence distance 5 cm, default convergence criteria
        (30 iterations, relative fitness/RMSE 1e-6), each frame against the previous one.

For each method it writes the trajectory (TUM format, camera-to-world, started at the ground-truth
pose of the first selected frame so that it lies in the ground-truth world frame) and a JSON with
per-frame timings split into I/O, preprocessing and registration. It also writes the ground truth
of the selected frames in TUM format (`groundtruth.txt`), which `fslam eval` needs.

Threads: Open3D 0.16's CPU code is parallelised with OpenMP (libgomp); there is no Python API to
set the thread count. `--threads N` sets OMP_NUM_THREADS before Open3D is imported, which is what
controls it: libgomp reads the variable once when it initialises, and Open3D's own thread estimate
(utility::EstimateMaxThreads, used by loops that pass num_threads explicitly) only honours
omp_get_max_threads() when OMP_NUM_THREADS (or OMP_DYNAMIC) is set -- otherwise it uses the number
of physical cores. Setting it after the import has no effect. The JSON records the process CPU
time and the peak thread count so that the setting can be checked after the fact.

Must run under Debian's interpreter (/usr/bin/python3), which is where python3-open3d lives.
Reads 7-Scenes folders (frame-NNNNNN.{color.jpg|color.png,depth.png,pose.txt}, optionally under
data/rgbd-frames/) and TUM folders (rgb.txt, depth.txt, groundtruth.txt, intrinsics.txt or
--intrinsics), with the same conventions as fslam's readers (docs/datasets.md).
"""

import argparse
import json
import os
import re
import sys
import time

# Timings are the point of this script, so the Open3D import is deferred until the thread count
# is known (see main()).
o3d = None
np = None

METHODS = ("rgbd", "gicp")
CLEAN_LOAD = 0.5  # cores of other work during a frame above which its timing is not "clean"


def parse_args(argv):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Example: /usr/bin/python3 tests/benchmarks/tracking_peers.py "
               "--dataset ../shared/data/redkitchen --frames 0:150 --threads 2 "
               "--methods gicp --out /tmp/peers",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", required=True, help="7-Scenes or TUM sequence folder")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--frames", default="0:600",
                   help="A:B, positions A..B-1 of the frame list, as fslam --frames "
                        "(default 0:600)")
    p.add_argument("--methods", default="rgbd,gicp",
                   help="comma-separated subset of: rgbd, gicp (default both)")
    p.add_argument("--threads", type=int, default=os.cpu_count(),
                   help="OpenMP threads for Open3D (default: all cores)")
    p.add_argument("--tag", default="",
                   help="suffix for output names, e.g. '_t1' gives gicp_t1.txt (default: none)")
    p.add_argument("--init", choices=("identity", "velocity"), default="identity",
                   help="initial guess of each frame-to-frame registration: identity, or the "
                        "previous frame's relative motion (constant velocity). Default identity, "
                        "Open3D's own default")
    p.add_argument("--voxel", type=float, default=0.02, help="GICP voxel size, m (default 0.02)")
    p.add_argument("--max-corr", type=float, default=0.05,
                   help="GICP max correspondence distance, m (default 0.05)")
    p.add_argument("--depth-trunc", type=float, default=4.0,
                   help="depth beyond this is dropped, m (default 4.0, OdometryOption's depth_max)")
    p.add_argument("--intrinsics", default="",
                   help="fx,fy,cx,cy override (TUM folders without intrinsics.txt need it)")
    p.add_argument("--progress-every", type=int, default=50,
                   help="print a progress line every N frames (default 50, 0: never)")
    args = p.parse_args(argv)
    args.methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in args.methods if m not in METHODS]
    if bad or not args.methods:
        p.error("--methods: unknown %s (choose from %s)" % (bad, ", ".join(METHODS)))
    if args.threads < 1:
        p.error("--threads must be >= 1")
    m = re.fullmatch(r"(\d*):(\d*)", args.frames)
    if not m:
        p.error("--frames must be A:B")
    args.first = int(m.group(1) or 0)
    args.last = int(m.group(2)) if m.group(2) else None
    return args


# ------------------------------------------------------------------------------------------------
# Poses and TUM files


def quat_from_rot(R):
    """(qx, qy, qz, qw) of a rotation matrix; Shepperd's branch choice keeps it well conditioned."""
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def rot_from_quat(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def orthonormalise(T):
    # 7-Scenes poses drift from orthonormality (docs/datasets.md); the nearest rotation keeps
    # the chained trajectory rigid.
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, 2] *= -1
        R = U @ Vt
    out = T.copy()
    out[:3, :3] = R
    out[3] = [0, 0, 0, 1]
    return out


def write_tum(path, stamps, poses, comment):
    with open(path, "w") as f:
        f.write("# %s\n# timestamp tx ty tz qx qy qz qw (camera-to-world)\n" % comment)
        for t, T in zip(stamps, poses):
            q = quat_from_rot(T[:3, :3])
            f.write("%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n"
                    % (t, T[0, 3], T[1, 3], T[2, 3], q[0], q[1], q[2], q[3]))


def read_tum(path):
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#"):
                rows.append([float(v) for v in line.replace(",", " ").split()[:8]])
    return np.array(rows)


def interpolate_pose(gt, t, max_gap=0.1):
    """Ground-truth pose at time t (slerp/lerp between the neighbours), None across gaps."""
    i = np.searchsorted(gt[:, 0], t)
    if i < len(gt) and abs(gt[i, 0] - t) < 1e-9:
        i0 = i1 = i
    elif 0 < i < len(gt) and gt[i, 0] - gt[i - 1, 0] <= max_gap:
        i0, i1 = i - 1, i
    else:
        return None
    a = 0.0 if i0 == i1 else (t - gt[i0, 0]) / (gt[i1, 0] - gt[i0, 0])
    q0, q1 = gt[i0, 4:8], gt[i1, 4:8]
    if np.dot(q0, q1) < 0:
        q1 = -q1
    theta = np.arccos(np.clip(np.dot(q0, q1) / np.linalg.norm(q0) / np.linalg.norm(q1), -1, 1))
    if theta < 1e-9:
        q = q0
    else:
        q = (np.sin((1 - a) * theta) * q0 + np.sin(a * theta) * q1) / np.sin(theta)
    T = np.eye(4)
    T[:3, :3] = rot_from_quat(q)
    T[:3, 3] = (1 - a) * gt[i0, 1:4] + a * gt[i1, 1:4]
    return T


# ------------------------------------------------------------------------------------------------
# Datasets: a list of frames {stamp, color, depth, pose (4x4 or None)} plus camera and depth scale


def open_7scenes(root, intrinsics_override):
    folder = root
    if not any(n.endswith(".depth.png") for n in os.listdir(folder)):
        folder = os.path.join(root, "data", "rgbd-frames")
    numbers = sorted(int(m.group(1)) for n in os.listdir(folder)
                     for m in [re.fullmatch(r"frame-(\d{6})\.depth\.png", n)] if m)
    frames = []
    for k in numbers:
        stem = os.path.join(folder, "frame-%06d" % k)
        color = stem + ".color.png" if os.path.exists(stem + ".color.png") else stem + ".color.jpg"
        pose = None
        if os.path.exists(stem + ".pose.txt"):
            pose = orthonormalise(np.loadtxt(stem + ".pose.txt").reshape(4, 4))
        frames.append(dict(stamp=k / 30.0, color=color, depth=stem + ".depth.png", pose=pose))
    fx, fy, cx, cy = 585.0, 585.0, 320.0, 240.0
    for d in (folder, root, os.path.join(root, "data"), os.path.dirname(folder),
              os.path.dirname(os.path.abspath(root))):
        k_file = os.path.join(d, "camera-intrinsics.txt")
        if os.path.exists(k_file):
            K = np.loadtxt(k_file).reshape(3, 3)
            fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
            break
    if intrinsics_override:
        fx, fy, cx, cy = intrinsics_override
    return frames, (fx, fy, cx, cy), 1000.0


def open_tum(root, intrinsics_override):
    def index(name):
        out = []
        with open(os.path.join(root, name)) as f:
            for line in f:
                parts = line.split()
                if parts and not parts[0].startswith("#"):
                    out.append((float(parts[0]), os.path.join(root, parts[1])))
        return out

    rgb, depth = index("rgb.txt"), index("depth.txt")
    # associate.py: greedy by smallest difference, each stamp once, pairs under 0.02 s
    cand = sorted((abs(a - b), i, j) for i, (a, _) in enumerate(rgb)
                  for j, (b, _) in enumerate(depth) if abs(a - b) < 0.02)
    used_r, used_d, pairs = set(), set(), []
    for _, i, j in cand:
        if i not in used_r and j not in used_d:
            used_r.add(i)
            used_d.add(j)
            pairs.append((i, j))
    pairs.sort()
    gt_path = os.path.join(root, "groundtruth.txt")
    gt = read_tum(gt_path) if os.path.exists(gt_path) else None
    frames = []
    for i, j in pairs:
        t = rgb[i][0]
        frames.append(dict(stamp=t, color=rgb[i][1], depth=depth[j][1],
                           pose=interpolate_pose(gt, t) if gt is not None else None))
    name = os.path.basename(os.path.abspath(root))
    presets = {"freiburg1": (517.3, 516.5, 318.6, 255.3), "fr1": (517.3, 516.5, 318.6, 255.3),
               "freiburg2": (520.9, 521.0, 325.1, 249.7), "fr2": (520.9, 521.0, 325.1, 249.7),
               "freiburg3": (535.4, 539.2, 320.1, 247.6), "fr3": (535.4, 539.2, 320.1, 247.6)}
    cam = intrinsics_override
    if not cam and os.path.exists(os.path.join(root, "intrinsics.txt")):
        with open(os.path.join(root, "intrinsics.txt")) as f:
            vals = [l.split() for l in f if l.strip() and not l.startswith("#")]
        cam = tuple(float(v) for v in vals[0][:4])
    if not cam:
        hits = {v for k, v in presets.items() if k in name}
        if len(hits) != 1:
            sys.exit("%s: no intrinsics.txt and no freiburg1/2/3 in the name: pass --intrinsics"
                     % root)
        cam = hits.pop()
    return frames, cam, 5000.0


def open_dataset(root, intrinsics_override):
    if os.path.exists(os.path.join(root, "rgb.txt")) and os.path.exists(
            os.path.join(root, "depth.txt")):
        return "tum", open_tum(root, intrinsics_override)
    return "7scenes", open_7scenes(root, intrinsics_override)


# ------------------------------------------------------------------------------------------------
# Tracking


def read_depth(path):
    """Depth image as o3d.geometry.Image (uint16), with the invalid 65535 code set to 0."""
    raw = np.asarray(o3d.io.read_image(path))
    if raw.dtype != np.uint16:
        sys.exit("%s: depth must be a 16-bit PNG, got %s" % (path, raw.dtype))
    raw = raw.copy()
    raw[raw == 65535] = 0
    return o3d.geometry.Image(raw)


class Timer:
    """Per-frame stage durations in milliseconds."""

    def __init__(self, stages):
        self.ms = {s: [] for s in stages}

    def add(self, stage, t0):
        self.ms[stage].append((time.perf_counter() - t0) * 1000.0)


def summarise(values):
    if not values:
        return None
    a = np.asarray(values)
    return dict(count=len(a), median_ms=float(np.median(a)), p99_ms=float(np.percentile(a, 99)),
                mean_ms=float(a.mean()), max_ms=float(a.max()))


def peak_threads():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("Threads:"):
                return int(line.split()[1])
    return None


def system_busy_s():
    """CPU seconds all processes on this machine have used so far (/proc/stat is not namespaced).

    Other work on the two cores (a build in another container, say) shows up as busy time that
    is not ours; it is the most common reason for a bad timing here, so each run records it."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    busy = v[0] + v[1] + v[2] + v[5] + v[6] + (v[7] if len(v) > 7 else 0)
    return busy / os.sysconf("SC_CLK_TCK")


def track(method, frames, cam, scale, args, log):
    """Chains frame-to-frame motions; returns poses (camera-to-world) and timing records."""
    fx, fy, cx, cy = cam
    first = np.asarray(o3d.io.read_image(frames[0]["depth"]))
    h, w = first.shape[:2]
    intr = o3d.camera.PinholeCameraIntrinsic(w, h, fx, fy, cx, cy)
    option = o3d.pipelines.odometry.OdometryOption()  # default; depth_max is 4 m
    jac = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()
    gicp_est = o3d.pipelines.registration.TransformationEstimationForGeneralizedICP()
    criteria = o3d.pipelines.registration.ICPConvergenceCriteria()
    knn = o3d.geometry.KDTreeSearchParamKNN(20)

    timer = Timer(("io", "preprocess", "register"))
    pose0 = frames[0]["pose"] if frames[0]["pose"] is not None else np.eye(4)
    poses = [pose0]
    prev = None
    motion = np.eye(4)  # last relative motion T_prev_cur, for --init velocity
    failures, points, fitness = 0, [], []
    cpu0, wall0, sys0 = time.process_time(), time.perf_counter(), system_busy_s()
    frame_load = []  # cores used by other processes while frame k was processed, k >= 1
    for k, fr in enumerate(frames):
        busy0, cpu_k, wall_k = system_busy_s(), time.process_time(), time.perf_counter()
        t0 = time.perf_counter()
        depth = read_depth(fr["depth"])
        color = o3d.io.read_image(fr["color"]) if method == "rgbd" else None
        timer.add("io", t0)

        t0 = time.perf_counter()
        if method == "rgbd":
            cur = o3d.geometry.RGBDImage.create_from_color_and_depth(
                color, depth, depth_scale=scale, depth_trunc=args.depth_trunc,
                convert_rgb_to_intensity=True)
        else:
            cloud = o3d.geometry.PointCloud.create_from_depth_image(
                depth, intr, depth_scale=scale, depth_trunc=args.depth_trunc)
            cur = cloud.voxel_down_sample(args.voxel)
            # Normals, not covariances: Open3D's GICP turns normals into the plane-shaped
            # covariances it expects (diag(eps,1,1) in the normal's frame); covariances from
            # estimate_covariances would be used raw, which is a different (worse) estimator.
            cur.estimate_normals(knn)
            points.append(len(cur.points))
        timer.add("preprocess", t0)

        if prev is not None:
            init = motion if args.init == "velocity" else np.eye(4)
            t0 = time.perf_counter()
            if method == "rgbd":
                ok, T, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
                    cur, prev, intr, init, jac, option)
            else:
                res = o3d.pipelines.registration.registration_generalized_icp(
                    cur, prev, args.max_corr, init, gicp_est, criteria)
                T, ok = res.transformation, res.fitness > 0
                fitness.append(res.fitness)
            timer.add("register", t0)
            if not ok:
                # A failed step keeps the initial guess, so the trajectory stays complete and the
                # ATE pays for the failure instead of hiding it.
                failures += 1
                T = init
            motion = np.array(T)
            poses.append(poses[-1] @ motion)
            own = time.process_time() - cpu_k
            frame_load.append(max(0.0, system_busy_s() - busy0 - own)
                              / max(time.perf_counter() - wall_k, 1e-6))
        prev = cur
        if args.progress_every and (k + 1) % args.progress_every == 0:
            log("%s: frame %d/%d, %.1f s, median register %.0f ms" % (
                method, k + 1, len(frames), time.perf_counter() - wall0,
                np.median(timer.ms["register"]) if timer.ms["register"] else 0.0))
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    foreign = max(0.0, system_busy_s() - sys0 - cpu)

    # The per-frame figure compared with fslam: preprocessing + registration of one frame
    # (image decoding excluded, reported separately as io).
    per_frame = [p + r for p, r in zip(timer.ms["preprocess"][1:], timer.ms["register"])]
    # This machine is shared: other tenants' builds come and go. Frames during which other
    # processes kept at least half a core busy are left out of the "clean" figures (the
    # /proc/stat clock ticks at 10 ms, so smaller loads cannot be told apart per frame).
    clean = [t for t, load in zip(per_frame, frame_load) if load < CLEAN_LOAD]
    record = dict(
        method=method, frames=len(frames), failures=failures, wall_s=wall, cpu_s=cpu,
        cpu_per_wall=cpu / wall if wall > 0 else None, peak_threads=peak_threads(),
        # Mean number of cores busy with other processes during the run; above ~0.1 the
        # timings are contaminated.
        foreign_load=foreign / wall if wall > 0 else None,
        timings={s: summarise(v) for s, v in timer.ms.items()},
        per_frame=summarise(per_frame),
        per_frame_clean=summarise(clean), clean_load_threshold=CLEAN_LOAD,
        per_frame_ms=dict(io=timer.ms["io"], preprocess=timer.ms["preprocess"],
                          register=timer.ms["register"], frame_load=frame_load))
    if method == "gicp":
        record["points_per_cloud"] = dict(median=float(np.median(points)),
                                          min=int(min(points)), max=int(max(points)))
        record["fitness"] = dict(median=float(np.median(fitness)) if fitness else None,
                                 min=float(min(fitness)) if fitness else None)
    return poses, record


def main(argv):
    global o3d, np
    args = parse_args(argv)
    # Before the import: libgomp reads these once at load time (see the module docstring).
    os.environ["OMP_NUM_THREADS"] = str(args.threads)
    import numpy as _np
    import open3d as _o3d
    np, o3d = _np, _o3d
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

    def log(msg):
        print("[tracking_peers] " + msg, flush=True)

    override = None
    if args.intrinsics:
        override = tuple(float(v) for v in args.intrinsics.split(","))
        if len(override) != 4:
            sys.exit("--intrinsics must be fx,fy,cx,cy")
    kind, (frames, cam, scale) = open_dataset(args.dataset, override)
    sel = frames[args.first:args.last]
    if len(sel) < 2:
        sys.exit("%s: selection %s holds %d frames, need at least 2"
                 % (args.dataset, args.frames, len(sel)))
    os.makedirs(args.out, exist_ok=True)
    log("%s %s, frames %d..%d (%d), fx %.1f fy %.1f cx %.1f cy %.1f, OMP_NUM_THREADS=%s, "
        "Open3D %s" % (kind, args.dataset, args.first, args.first + len(sel) - 1, len(sel),
                       cam[0], cam[1], cam[2], cam[3], os.environ["OMP_NUM_THREADS"],
                       o3d.__version__))

    gt = [(f["stamp"], f["pose"]) for f in sel if f["pose"] is not None]
    if gt:
        write_tum(os.path.join(args.out, "groundtruth.txt"), [s for s, _ in gt],
                  [p for _, p in gt], "ground truth of %s frames %s" % (args.dataset, args.frames))
    if sel[0]["pose"] is None:
        log("warning: no ground-truth pose for the first frame; trajectories start at identity")

    report = dict(dataset=os.path.abspath(args.dataset), kind=kind, frames=args.frames,
                  frame_count=len(sel), intrinsics=cam, depth_scale=scale,
                  threads=args.threads, omp_num_threads=os.environ["OMP_NUM_THREADS"],
                  omp_wait_policy=os.environ.get("OMP_WAIT_POLICY", ""),
                  open3d_version=o3d.__version__, init=args.init, depth_trunc=args.depth_trunc,
                  gicp=dict(voxel_m=args.voxel, max_correspondence_m=args.max_corr,
                            normals_knn=20, epsilon=1e-3, max_iteration=30),
                  rgbd=dict(jacobian="hybrid", iterations=[20, 10, 5], depth_diff_max=0.03,
                            depth_max=4.0),
                  methods={})
    for method in args.methods:
        log("%s: start" % method)
        poses, rec = track(method, sel, cam, scale, args, log)
        traj = os.path.join(args.out, "%s%s.txt" % (method, args.tag))
        write_tum(traj, [f["stamp"] for f in sel], poses,
                  "Open3D %s %s, frames %s, %d threads, init %s"
                  % (o3d.__version__, method, args.frames, args.threads, args.init))
        rec["trajectory"] = traj
        report["methods"][method] = rec
        pf, pc = rec["per_frame"], rec["per_frame_clean"]
        log("%s: done in %.1f s, per frame median %.1f ms p99 %.1f ms (register median %.1f, "
            "preprocess median %.1f, io median %.1f), %d failures, cpu/wall %.2f, threads %s, "
            "foreign load %.2f cores; %d clean frames: median %.1f ms p99 %.1f ms"
            % (method, rec["wall_s"], pf["median_ms"], pf["p99_ms"],
               rec["timings"]["register"]["median_ms"],
               rec["timings"]["preprocess"]["median_ms"], rec["timings"]["io"]["median_ms"],
               rec["failures"], rec["cpu_per_wall"], rec["peak_threads"], rec["foreign_load"],
               pc["count"] if pc else 0, pc["median_ms"] if pc else float("nan"),
               pc["p99_ms"] if pc else float("nan")))
        with open(os.path.join(args.out, "peers%s.json" % args.tag), "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
