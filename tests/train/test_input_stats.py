#!/usr/bin/python3
"""The input statistics in Python (weights/input_stats.py) against the C
ones (src/input_stats.c, through input_stats_dump), the weights stamped by
weights/stamp_range.py and by train.py --export as the C loader reads them,
and the samples weights/dataset.py trains on as the C library sanitises
them.

    test_input_stats.py --dump BUILD/tests/train/input_stats_dump --work DIR

Exits 77 (skipped) without numpy or OpenImageIO; the train.py case also
needs torch and is skipped alone without it.
"""
import argparse
import contextlib
import io
import json
import math
import os
import shutil
import subprocess
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
WEIGHTS = os.path.join(HERE, "..", "..", "weights")
sys.path.insert(0, WEIGHTS)

try:
    import numpy as np
    import OpenImageIO  # noqa: F401
except ImportError as e:  # pragma: no cover - depends on the machine
    print(f"train.input_stats skipped: {e} (install python3-numpy python3-openimageio)")
    sys.exit(77)

import dataset  # noqa: E402
import input_stats  # noqa: E402
import sample_rule  # noqa: E402
import stamp_range  # noqa: E402
import synth_dataset  # noqa: E402

ARGS = None


def dump(*argv):
    r = subprocess.run([ARGS.dump, *argv], capture_output=True, text=True)
    if r.returncode != 0:
        raise AssertionError(f"input_stats_dump {' '.join(argv)}: {r.stderr}")
    return json.loads(r.stdout)


def features(alphas):
    """[h][w][spp][6] with the given alphas ([h][w][spp]); covered samples
    get plausible other features, uncovered ones all zeros."""
    a = np.asarray(alphas, np.float32)
    f = np.zeros(a.shape + (6,), np.float32)
    cov = a > 0
    f[..., 0] = np.where(cov, 0.7, 0)
    f[..., 1] = np.where(cov, 0.1, 0)
    f[..., 2] = np.where(cov | np.isnan(a) | (a < 0), a, 0)   # keep the odd values
    f[..., 3] = np.where(cov, 0.5, 0)
    return f


def write_features(path, feat, half=False):
    h, w, spp, _ = feat.shape
    names = [f"S{k}.{n}" for k in range(spp) for n in dataset.FEATURES]
    dataset.write_exr(path, names, feat.reshape(h, w, -1), half=half)


def same(py, c):
    for k in ["hair_pixels", "full_pixels"] + input_stats.STATS:
        a, b = py[k], c[k]
        if b is None:
            if not math.isnan(a):
                return f"{k}: python {a!r}, C null"
        elif a != b:
            return f"{k}: python {a!r}, C {b!r}"
    return None


class Stats(unittest.TestCase):
    def test_known_frame(self):
        """The constructed frame of tests/core/test_input_stats.c."""
        rows = [[0, 0, 0, 0], [.25, 0, 0, 0], [.5, .5, .5, .5], [.125, .375, 0, 0],
                [1, 1, 1, 1], [.75, .25, .5, 0], [0, 0, 0, 0], [.0625, 0, 0, 0]]
        feat = features(np.array(rows).reshape(2, 4, 4))
        s = input_stats.frame_stats(feat)
        self.assertEqual((s["hair_pixels"], s["full_pixels"]), (6, 2))
        self.assertEqual(s["strand_alpha_p50"], 0.25)
        self.assertEqual(s["strand_alpha_p90"], 1.0)
        self.assertEqual(s["full_coverage"], 2 / 6)
        self.assertEqual(s["hair_fraction"], 0.75)
        self.assertEqual(s["long_side"], 4.0)
        self.assertEqual(input_stats.frame_stats(feat.reshape(2, 4, 24))["strand_alpha_p50"], 0.25)
        s1 = input_stats.frame_stats(feat, spp=1)   # first samples only
        self.assertEqual((s1["hair_pixels"], s1["full_coverage"]), (6, 1.0))
        empty = input_stats.frame_stats(np.zeros((3, 5, 4, 6), np.float32))
        self.assertEqual(empty["hair_fraction"], 0.0)
        self.assertTrue(math.isnan(empty["strand_alpha_p50"]))
        self.assertEqual(input_stats.frame_stats(features([[[0.3]]]))["strand_alpha_p50"],
                         0.298828125)

    def test_equal_to_c(self):
        """Bit for bit on rendered-like frames and on frames of odd alphas
        (NaN, negative, infinite, subnormal, tiny, above 1, every spp), in
        float32 and half EXR files."""
        rng = np.random.default_rng(3)
        frames = []
        for style in ("straight", "curly"):
            names, img = synth_dataset.render_frame(style, 40, 32, 4, [], 11)
            idx = [names.index(f"S{k}.{f}") for k in range(4) for f in dataset.FEATURES]
            frames.append(img[..., idx].reshape(32, 40, 4, 6))
        for spp in (1, 2, 4, 16):
            a = rng.uniform(0, 1, (33, 29, spp)).astype(np.float32) ** 3
            a[rng.random(a.shape) < 0.5] = 0
            odd = rng.random(a.shape)
            a[odd < 0.01] = np.nan
            a[(odd >= 0.01) & (odd < 0.02)] = -0.5
            a[(odd >= 0.02) & (odd < 0.03)] = np.inf
            a[(odd >= 0.03) & (odd < 0.04)] = 1e-41      # float32 subnormal
            a[(odd >= 0.04) & (odd < 0.05)] = 3e-6       # below 2^-16
            a[(odd >= 0.05) & (odd < 0.06)] = 1.7
            frames.append(features(a))
        for i, feat in enumerate(frames):
            for half in (False, True):
                path = os.path.join(ARGS.work, f"frame{i}{'h' if half else ''}.exr")
                write_features(path, feat, half)
                names, data = dataset.read_exr(path)   # what C reads, as float32
                spp = feat.shape[2]
                back = dataset.pick_channels(
                    names, data, [f"S{k}.{f}" for k in range(spp) for f in dataset.FEATURES])
                back = back.reshape(feat.shape[0], feat.shape[1], spp, 6)
                for s in sorted({1, spp}):
                    py = input_stats.frame_stats(back, s)
                    c = dump("stats", path, str(s))
                    diff = same(py, c)
                    self.assertIsNone(diff, f"{path} at {s} spp: {diff}")


class Stamp(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.data = os.path.join(ARGS.work, "data")
        synth_dataset.main(["--out", cls.data, "--styles", "straight,wavy", "--count", "3",
                            "--size", "32x32", "--spp", "4", "--st", "", "--seed", "2"])

    def test_stamp_range(self):
        w = os.path.join(ARGS.work, "small.safetensors")
        subprocess.run([ARGS.dump, "weights", w], check=True)
        self.assertIsNone(dump("range", w))
        before = open(w, "rb").read()
        r = subprocess.run([sys.executable, os.path.join(WEIGHTS, "stamp_range.py"), w,
                            "--data", self.data, "--quiet"], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        # The same training split as train.py: 6 frames, 1 held out.
        train = stamp_range.training_frames(self.data, "", 0.1)
        self.assertEqual(len(train), 5)
        stats = [input_stats.frame_stats(
            dataset.load_frame(e["file"], 4, np.float32, sanitise=False)[0], 4) for e in train]
        want = input_stats.input_range(stats, 4)
        got = dump("range", w)
        self.assertEqual(got, want)   # the C loader reads back every bit
        self.assertEqual(got["frames"], 5)
        self.assertTrue(got["strand_alpha_p50"][0] <= got["strand_alpha_p50"][1])
        # Tensors untouched: the file ends with the same bytes.
        after = open(w, "rb").read()
        tail = len(before) - 8 - int.from_bytes(before[:8], "little")
        self.assertEqual(after[-tail:], before[-tail:])
        # Training frames are inside, and so is a frame of the same hair at
        # twice the size (a training frame tiled 2x2: every statistic but
        # long_side the same), since the range records no size.
        self.assertEqual(dump("check", w, train[0]["file"]), 0)
        self.assertNotIn("long_side", got)
        big = os.path.join(ARGS.work, "tiled.exr")
        feat = dataset.load_frame(train[0]["file"], 4, np.float32)[0]
        write_features(big, np.tile(feat, (2, 2, 1, 1)))
        self.assertEqual(dump("stats", big, "4")["long_side"], 2 * max(feat.shape[:2]))
        self.assertEqual(dump("check", w, big), 0)
        wide = os.path.join(ARGS.work, "wide.exr")
        write_features(wide, features(np.ones((16, 16, 4), np.float32)))
        mask = dump("check", w, wide)
        self.assertTrue(mask & (1 << input_stats.STATS.index("strand_alpha_p50")), mask)
        self.assertTrue(mask & (1 << input_stats.STATS.index("full_coverage")), mask)

    def test_stamp_join(self):
        # A range the file records is replaced, and said so; --join keeps it
        # and adds the new frames' (weights fine-tuned from others learnt both).
        other = os.path.join(ARGS.work, "other")
        shutil.rmtree(other, ignore_errors=True)
        synth_dataset.main(["--out", other, "--styles", "straight", "--count", "3",
                            "--size", "24x24", "--spp", "4", "--st", "", "--seed", "9"])
        w = os.path.join(ARGS.work, "joined.safetensors")
        subprocess.run([ARGS.dump, "weights", w], check=True)
        stamp = [sys.executable, os.path.join(WEIGHTS, "stamp_range.py"), w, "--quiet"]
        r = subprocess.run(stamp + ["--data", self.data], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stderr, "")    # nothing recorded before: nothing replaced
        first = dump("range", w)
        r = subprocess.run(stamp + ["--data", other, "--join"], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        alone = stamp_range.range_of_frames(stamp_range.training_frames(other, "", 0.1), 4)
        got = dump("range", w)
        self.assertEqual(got, input_stats.union_range(alone, first))
        self.assertEqual(got["frames"], first["frames"] + alone["frames"])
        r = subprocess.run(stamp + ["--data", other], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn(f"{w}: replaces the input_range {w} recorded (over {got['frames']} "
                      "frames); add --join", r.stderr)
        self.assertEqual(dump("range", w), alone)
        # A range of another version of the definitions is not joined: said
        # before any frame is measured.
        header, body = stamp_range.read_safetensors_header(w)
        old = json.loads(header["__metadata__"]["input_range"])
        old["definition"] = input_stats.DEFINITION + 1
        header["__metadata__"]["input_range"] = json.dumps(old)
        stamp_range.write_safetensors_header(w, header, body)
        r = subprocess.run(stamp + ["--data", other, "--join"], capture_output=True, text=True)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn(f"its input_range has definition {input_stats.DEFINITION + 1}, these "
                      f"frames' {input_stats.DEFINITION}: the two cannot be joined", r.stderr)

    def test_crop_counts_at_full_size(self):
        # A crop of a 1024 frame: its statistics and its regime row say 1024.
        crop = os.path.join(ARGS.work, "crop")
        shutil.rmtree(crop, ignore_errors=True)
        shutil.copytree(self.data, crop)
        man = os.path.join(crop, "manifest.json")
        with open(man) as f:
            doc = json.load(f)
        frames = doc["frames"]
        frames[0]["full_width"], frames[0]["full_height"] = 1024, 768
        with open(man, "w") as f:
            json.dump(doc, f)
        entries = dataset.read_manifest(crop)
        e = next(x for x in entries if os.path.basename(x["file"]) == frames[0]["file"])
        feat = dataset.load_frame(e["file"], 4, np.float32)[0]
        self.assertEqual(dataset.entry_stats(e, feat, 4)["long_side"], 1024.0)
        self.assertEqual(input_stats.frame_stats(feat, 4)["long_side"], 32.0)
        # A trained range records no size: a frame larger than any trained
        # on is not outside for that.
        rng = stamp_range.range_of_frames(entries, 4)
        self.assertNotIn("long_side", rng)
        self.assertIn("hair_fraction", rng)
        r = subprocess.run([sys.executable, os.path.join(WEIGHTS, "regime_table.py"),
                            "train=" + crop, "plain=" + self.data],
                           capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        rows = {}
        for line in r.stdout.splitlines():
            if line.startswith("| train |") or line.startswith("| plain |"):
                rows.setdefault(line.split("|")[1].strip(), []).append(
                    [c.strip() for c in line.strip("|").split("|")[1:]])
        # Four tables per set; every frame table totals the 6 frames.
        self.assertEqual(len(rows["train"]), 4, r.stdout)
        for t in (0, 2, 3):
            self.assertEqual(rows["train"][t][0], "6")
            self.assertEqual(sum(int(c.split()[0]) for c in rows["train"][t][1:]), 6)
        self.assertEqual(rows["train"][3][1:], ["5 (83%)", "0 (0%)", "1 (17%)"])
        self.assertEqual(rows["plain"][3][1:], ["6 (100%)", "0 (0%)", "0 (0%)"])
        # The pixel table counts hair pixels: its total is the frames' hair pixels.
        hair = sum(int((input_stats.strand_alpha(
            dataset.load_frame(x["file"], 4, np.float32)[0], 4)[1] > 0).sum()) for x in entries)
        self.assertEqual(int(rows["train"][1][0]), hair)

    def test_train_export(self):
        try:
            import torch  # noqa: F401
        except ImportError:
            self.skipTest("no torch")
        out = os.path.join(ARGS.work, "run")
        exp = os.path.join(ARGS.work, "trained.safetensors")
        r = subprocess.run([sys.executable, os.path.join(WEIGHTS, "train.py"), "--data", self.data,
                            "--variant", "Small", "--out", out, "--steps", "2", "--batch", "2",
                            "--crop", "32", "--threads", "1", "--device", "cpu", "--val-every", "2",
                            "--export", exp], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        got = dump("range", exp)
        self.assertEqual(got["frames"], 5)
        self.assertEqual(got["spp"], 4)
        train = stamp_range.training_frames(self.data, "straight,wavy", 0.1)
        stats = [input_stats.frame_stats(
            dataset.load_frame(e["file"], 4, np.float32, sanitise=False)[0], 4) for e in train]
        self.assertEqual(got, input_stats.input_range(stats, 4))


class Sanitise(unittest.TestCase):
    """Training reads a frame's samples as the C library sanitises them
    before the network (protocol/FEATURES.md, "Out-of-contract values"):
    a NaN or infinite feature, a feature out of range (a UINT channel's
    integers among them) or a negative alpha meant one thing in training
    and another in `hairfilter infer`."""

    def frame(self, half):
        rng = np.random.default_rng(8)
        h, w, spp = 9, 11, 4
        feat = np.stack([rng.uniform(0, 2, (h, w, spp)), rng.uniform(0, 1, (h, w, spp)),
                         rng.uniform(0.05, 1, (h, w, spp)), rng.uniform(0, 1, (h, w, spp)),
                         rng.uniform(-1, 1, (h, w, spp)), rng.uniform(-1, 1, (h, w, spp))],
                        -1).astype(np.float32)
        feat[0, 0, 0] = 0                       # uncovered, left alone
        feat[0, 1, 0] = -0.0                    # uncovered with -0.0
        odd = [np.nan, np.inf, -np.inf, -0.5, 70.0, 3e38, 1e-41, -0.0, 1.5, -3.0]
        for i, v in enumerate(odd):
            for f in range(6):
                feat[1 + i % 8, (i + f) % w, (i + f) % spp, f] = v
        feat[8, 8, 1, 2] = 0.0                  # alpha 0 beside other features
        names = [f"S{k}.{n}" for k in range(spp) for n in dataset.FEATURES]
        names += ["gt.color", "gt.highlight", "gt.alpha"]
        gt = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
        path = os.path.join(ARGS.work, f"odd{'h' if half else ''}.exr")
        dataset.write_exr(path, names, np.concatenate([feat.reshape(h, w, -1), gt], -1), half)
        return path, feat

    def test_samples_are_those_c_sanitises(self):
        for half in (False, True):
            path, feat = self.frame(half)
            c_path = os.path.join(ARGS.work, "c.f32")
            subprocess.run([ARGS.dump, "sanitise", path, "4", c_path], check=True)
            c = np.fromfile(c_path, np.float32).reshape(feat.shape)
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                py, _ = dataset.load_frame(path, dtype=np.float32)
            self.assertTrue(np.isfinite(py).all())
            bad = np.argwhere(py.view(np.uint32) != c.view(np.uint32))
            self.assertEqual(bad.size, 0, f"{path}: first difference at {bad[:1]}: python "
                             f"{py[tuple(bad[0])] if bad.size else ''}, C "
                             f"{c[tuple(bad[0])] if bad.size else ''}")
            self.assertIn(f"{path}: ", err.getvalue())
            self.assertIn("sanitised (protocol/FEATURES.md", err.getvalue())
            raw, _ = dataset.load_frame(path, dtype=np.float32, sanitise=False)
            self.assertTrue(np.isnan(raw).any(), "sanitise=False reads the file's values")

    def test_estimate_rule(self):
        est = np.array([[[0, 0, 0], [-0.0, 0, 0], [np.nan, 0.1, 0.5], [0.5, 0.1, -1],
                         [0.5, 0.1, 0], [80, -1, 2], [0.5, 0.2, 0.3]]], np.float32)
        fixed, changed = sample_rule.sanitise_estimate(est)
        want = [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [64, 0, 1],
                [0.5, 0.2, 0.3]]
        self.assertEqual(fixed[0].tolist(), np.array(want, np.float32).tolist())
        self.assertEqual(changed[0].tolist(), [False, False, True, True, True, True, False])

    def test_nonfinite_ground_truth_is_refused_naming_the_pixel(self):
        names = [f"S0.{n}" for n in dataset.FEATURES] + ["gt.color", "gt.highlight", "gt.alpha"]
        img = np.full((3, 4, 9), 0.5, np.float32)
        img[2, 1, 7] = np.inf
        path = os.path.join(ARGS.work, "gt_inf.exr")
        dataset.write_exr(path, names, img)
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.load_frame(path)
        self.assertIn("gt.highlight = inf at pixel (1, 2)", str(e.exception))


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--dump", required=True)
    ap.add_argument("--work", required=True)
    ARGS, rest = ap.parse_known_args()
    shutil.rmtree(ARGS.work, ignore_errors=True)
    os.makedirs(ARGS.work)
    unittest.main(argv=[sys.argv[0]] + rest, verbosity=2)


if __name__ == "__main__":
    main()
