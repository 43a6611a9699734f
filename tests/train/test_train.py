#!/usr/bin/python3
"""End-to-end test of the training recipe (weights/train.py).

    test_train.py --roundtrip BUILD/tests/train/weights_roundtrip \
                  --hairfilter BUILD/hairfilter --work DIR

Generates a tiny synthetic dataset, checks the augmentation against the
geometry, trains a few dozen steps (the loss must fall), checks that a run
stopped and resumed equals an uninterrupted one, round-trips the export
through the C loader/writer bit-exactly and compares C inference (cpu-ref)
with PyTorch. Exits 77 (skipped) when torch or OpenImageIO is missing.
"""
import argparse
import contextlib
import io
import json
import os
import runpy
import shutil
import struct
import subprocess
import tempfile
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
WEIGHTS = os.path.join(HERE, "..", "..", "weights")
sys.path.insert(0, WEIGHTS)

try:
    import numpy as np
    import torch
    import OpenImageIO
except ImportError as e:  # pragma: no cover - depends on the machine
    print(f"train.recipe skipped: {e} (install python3-torch python3-openimageio)")
    sys.exit(77)

import dataset  # noqa: E402
import hfnet  # noqa: E402
import synth_dataset  # noqa: E402
import train  # noqa: E402

ARGS = None
SIZE = 64


def run_train(*argv):
    """weights/train.py in a subprocess, as a user runs it."""
    # On the CPU wherever it runs: the resume test needs bit-reproducible steps.
    cmd = [sys.executable, os.path.join(WEIGHTS, "train.py"), "--threads", "1",
           "--device", "cpu", *argv]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed:\n{r.stderr}")
    return r


def read_log(run):
    with open(os.path.join(run, "log.jsonl")) as f:
        return [json.loads(line) for line in f]


class Recipe(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        torch.set_num_threads(1)
        cls.work = ARGS.work
        shutil.rmtree(cls.work, ignore_errors=True)
        os.makedirs(cls.work)
        cls.data = os.path.join(cls.work, "data")
        synth_dataset.main(["--out", cls.data, "--styles", "straight,wavy", "--count", "10",
                            "--size", f"{SIZE}x{SIZE}", "--st", "", "--seed", "3"])

    # -- data ----------------------------------------------------------------

    def test_manifest_and_split(self):
        entries = dataset.read_manifest(self.data)
        self.assertEqual(len(entries), 20)
        self.assertEqual({e["style"] for e in entries}, {"straight", "wavy"})
        tr, va = dataset.split_frames(entries, 0.1)
        self.assertEqual(len(va), 2)
        self.assertEqual(len(tr) + len(va), 20)
        # The split depends on names only: the same for any listing order.
        tr2, va2 = dataset.split_frames(list(reversed(entries)), 0.1)
        self.assertEqual(sorted(e["file"] for e in va), sorted(e["file"] for e in va2))
        self.assertFalse({e["file"] for e in va} & {e["file"] for e in tr})

    def test_multipart_frame_reads_its_feature_part(self):
        """A frame whose features are one part of a multi-part EXR (after an
        RGBA part) is read from that part, as the C reader chooses it; it was
        read from part 0 and refused as "not a feature file". Two parts with
        S0.color are refused, naming the parts."""
        import OpenImageIO as oiio
        frame = dataset.read_manifest(self.data)[0]["file"]
        names, data = dataset.read_exr(frame)
        h, w, c = data.shape
        rgba = oiio.ImageSpec(w, h, 4, oiio.HALF)
        rgba.channelnames = ("R", "G", "B", "A")
        rgba.attribute("name", "rgba")
        feat = oiio.ImageSpec(w, h, c, oiio.FLOAT)
        feat.channelnames = tuple(names)
        feat.attribute("name", "features")
        feat0 = oiio.ImageSpec(feat)
        feat0.attribute("name", "features0")
        for label, first in (("one", rgba), ("two", feat0)):
            path = os.path.join(self.work, f"multipart_{label}.exr")
            out = oiio.ImageOutput.create(path)
            self.assertTrue(out.open(path, (first, feat)), oiio.geterror())
            self.assertTrue(out.write_image(data if label == "two" else
                                            np.zeros((h, w, 4), np.float32)))
            self.assertTrue(out.open(path, feat, "appendsubimage"))
            self.assertTrue(out.write_image(data))
            out.close()
            if label == "one":
                n2, d2 = dataset.read_exr(path)
                self.assertEqual(n2, names)
                self.assertTrue(np.array_equal(d2.view(np.uint32), data.view(np.uint32)))
                f1, t1 = dataset.load_frame(frame)
                f2, t2 = dataset.load_frame(path)
                self.assertTrue(np.array_equal(f1, f2) and np.array_equal(t1, t2))
            else:
                with self.assertRaises(dataset.DatasetError) as e:
                    dataset.read_exr(path)
                self.assertIn("2 parts, several with channel S0.color", str(e.exception))

    def test_frame_cut_short_outside_its_first_level_or_part_is_refused(self):
        """A file cut short where OpenImageIO does not read (a mipmapped
        frame's smaller levels, the part after the features) is refused as
        incomplete, as the C reader refuses it; it was read as whole. A
        damaged chunk is named."""
        import OpenImageIO as oiio
        data_dir = os.path.join(HERE, "..", "data")
        whole = os.path.join(data_dir, "exr-mipmap.exr")
        names, px = dataset.read_exr(whole)
        self.assertEqual((px.shape, names[:1]), ((6, 8, 6), ["S0.alpha"]))
        with open(whole, "rb") as f:
            blob = f.read()
        cut = os.path.join(self.work, "mipmap_cut.exr")
        with open(cut, "wb") as f:
            f.write(blob[:-10])   # inside the 1x1 level's chunk
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(cut)
        self.assertIn(f"{cut}: truncated / incomplete file: it ends (at {len(blob) - 10} bytes) "
                      "inside the data of a chunk", str(e.exception))
        self.assertIn("write or copy the file again", str(e.exception))
        # The features, then an RGBA part cut short.
        h, w, c = px.shape
        feat = oiio.ImageSpec(w, h, c, oiio.FLOAT)
        feat.channelnames = tuple(names)
        feat.attribute("name", "features")
        rgba = oiio.ImageSpec(w, h, 4, oiio.HALF)
        rgba.channelnames = ("R", "G", "B", "A")
        rgba.attribute("name", "rgba")
        path = os.path.join(self.work, "multipart_cut.exr")
        out = oiio.ImageOutput.create(path)
        self.assertTrue(out.open(path, (feat, rgba)), oiio.geterror())
        self.assertTrue(out.write_image(px))
        self.assertTrue(out.open(path, rgba, "appendsubimage"))
        self.assertTrue(out.write_image(np.ones((h, w, 4), np.float32)))
        out.close()
        self.assertEqual(dataset.read_exr(path)[0], names)
        with open(path, "rb") as f:
            blob = f.read()
        with open(path, "wb") as f:
            f.write(blob[:-3])
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(path)
        self.assertIn("truncated / incomplete file", str(e.exception))
        # A damaged chunk of the part read: ZIP data that does not inflate
        # is named.
        scan = os.path.join(self.work, "scanlines_damaged.exr")
        dataset.write_exr(scan, names, px)
        with open(scan, "rb") as f:
            blob = bytearray(f.read())
        blob[-30:-5] = b"\xab" * 25
        with open(scan, "wb") as f:
            f.write(blob)
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(scan)
        self.assertIn("scanlines 0-5: its ZIP data cannot be inflated", str(e.exception))
        self.assertIn("the file is damaged, write it again", str(e.exception))

    def test_level_mode_over_other_levels_is_refused_as_the_c_reader_refuses_it(self):
        """A tiled frame whose header names another level mode than its
        tiles were written in (RIP levels or one level over MIP levels) is
        refused as damaged by both readers; OpenImageIO read its first level
        and training took the frame hairfilter refuses. The frames as
        written (tests/data/exr-mipmap.exr) read in both."""
        data_dir = os.path.join(HERE, "..", "data")
        whole = os.path.join(data_dir, "exr-mipmap.exr")
        with open(whole, "rb") as f:
            blob = bytearray(f.read())
        at = blob.index(b"tiles\0tiledesc\0") + len(b"tiles\0tiledesc\0") + 4 + 8
        self.assertEqual(blob[at] & 0xF, 1)   # MIP levels
        weights = os.path.join(WEIGHTS, "base_1spp.safetensors")
        for mode, name in ((2, "RIP levels"), (0, "one level")):
            blob[at] = (blob[at] & 0xF0) | mode
            path = os.path.join(self.work, f"levels_{mode}.exr")
            with open(path, "wb") as f:
                f.write(blob)
            with self.assertRaises(dataset.DatasetError) as e:
                dataset.read_exr(path)
            self.assertIn(f"{path}: the EXR header contradicts itself: its tile description "
                          f"(4x4 tiles, {name})", str(e.exception))
            r = subprocess.run([ARGS.hairfilter, "infer", "--weights", weights, "--in", path,
                                "--out", path + ".result.exr", "--backend", "cpu-ref"],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("the file is damaged", r.stderr)
        r = subprocess.run([ARGS.hairfilter, "infer", "--weights", weights, "--in", whole,
                            "--out", os.path.join(self.work, "levels_ok.exr"), "--backend",
                            "cpu-ref"], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)

    def test_data_window_larger_than_the_file_holds_is_refused(self):
        """A header claiming a data window its small file cannot hold (a
        damaged one) is refused before the pixels are read, as the C reader
        refuses it; OpenImageIO allocated what it claimed (755 MB for a
        7 KB file) and returned it, garbage, as the frame."""
        import OpenImageIO as oiio
        names = [f"S0.{f}" for f in dataset.FEATURES]
        spec = oiio.ImageSpec(16, 12, 6, oiio.HALF)
        spec.channelnames = tuple(names)
        spec.attribute("compression", "none")
        path = os.path.join(self.work, "claims.exr")
        out = oiio.ImageOutput.create(path)
        self.assertTrue(out.open(path, spec) and out.write_image(np.ones((12, 16, 6), np.float32)))
        out.close()
        self.assertEqual(dataset.read_exr(path)[1].shape, (12, 16, 6))
        with open(path, "rb") as f:
            blob = bytearray(f.read())
        at = blob.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
        struct.pack_into("<i", blob, at + 8, (1 << 20) - 1)   # max.x
        with open(path, "wb") as f:
            f.write(blob)
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(path)
        self.assertIn(f"{path}: its data window claims 1048576x12 pixels of 6 channels",
                      str(e.exception))
        self.assertIn("the file is damaged", str(e.exception))

    def test_channel_listed_twice_is_refused(self):
        """A frame whose channel list names a channel twice is refused,
        naming it, as the C reader refuses it; OpenImageIO kept one of the
        two and training read a frame of one channel fewer."""
        names = [f"S0.{f}" for f in dataset.FEATURES]
        path = os.path.join(self.work, "dup.exr")
        dataset.write_exr(path, names, np.full((3, 4, 6), 0.5, np.float32))
        with open(path, "rb") as f:
            blob = f.read()
        with open(path, "wb") as f:
            f.write(blob.replace(b"S0.color\0", b"S0.alpha\0", 1))
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(path)
        self.assertIn(f'{path}: channel "S0.alpha" is listed twice in the channel list of part 0',
                      str(e.exception))
        weights = os.path.join(WEIGHTS, "base_1spp.safetensors")
        r = subprocess.run([ARGS.hairfilter, "infer", "--weights", weights, "--in", path,
                            "--out", path + ".result.exr"], capture_output=True, text=True)
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertIn('channel "S0.alpha" is listed twice', r.stderr)

    def test_header_that_does_not_describe_its_chunks_is_refused(self):
        """A header changed after its pixels were written (a channel's type,
        the data window's width) so that a chunk holds another number of
        bytes than its pixels: OpenEXR's C++ library read it into garbage
        values with no error, and training took them; it is refused, as the
        C reader refuses it, naming the chunk."""
        import OpenImageIO as oiio
        names = [f"S0.{f}" for f in dataset.FEATURES]
        weights = os.path.join(WEIGHTS, "base_1spp.safetensors")
        for comp in ("none", "zip"):
            spec = oiio.ImageSpec(16, 12, 6, oiio.HALF if comp == "none" else oiio.FLOAT)
            spec.channelnames = tuple(names)
            spec.attribute("compression", comp)
            path = os.path.join(self.work, f"chunks_{comp}.exr")
            out = oiio.ImageOutput.create(path)
            rng = np.random.default_rng(2)
            self.assertTrue(out.open(path, spec) and
                            out.write_image(rng.uniform(0, 1, (12, 16, 6)).astype(np.float32)))
            out.close()
            self.assertEqual(dataset.read_exr(path)[1].shape, (12, 16, 6))
            with open(path, "rb") as f:
                blob = bytearray(f.read())
            if comp == "none":   # S0.alpha HALF -> FLOAT
                at = blob.index(b"S0.alpha\0") + 9
                struct.pack_into("<i", blob, at, 2)
                want = "scanlines 0-0 holds 192 bytes of pixels, but its 16x1 pixels of 6 " \
                       "channels are 224 bytes: the header does not describe its data"
            else:                # 15 columns instead of 16
                at = blob.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
                struct.pack_into("<i", blob, at + 8, 14)
                want = "scanlines 0-11 holds 4608 bytes of pixels, but its 15x12 pixels of 6 " \
                       "channels are 4320 bytes: the header does not describe its data"
            with open(path, "wb") as f:
                f.write(blob)
            with self.assertRaises(dataset.DatasetError) as e:
                dataset.read_exr(path)
            self.assertIn(f"{path}: {want}", str(e.exception))
            r = subprocess.run([ARGS.hairfilter, "infer", "--weights", weights, "--in", path,
                                "--out", path + ".result.exr"], capture_output=True, text=True)
            self.assertEqual(r.returncode, 1, r.stderr)
            self.assertIn("the file is damaged", r.stderr)

    def test_deep_frame_is_refused_saying_so(self):
        """A deep frame is refused as the C reader refuses it, with the
        flatten command; it was called "damaged or incomplete" after an
        OpenImageIO error about a file not open."""
        import OpenImageIO as oiio
        names = [f"S0.{f}" for f in dataset.FEATURES]
        spec = oiio.ImageSpec(4, 3, 6, oiio.FLOAT)
        spec.channelnames = tuple(names)
        spec.deep = True
        spec.attribute("compression", "zips")
        path = os.path.join(self.work, "deep.exr")
        out = oiio.ImageOutput.create(path)
        self.assertTrue(out.open(path, spec), oiio.geterror())
        deep = oiio.DeepData()
        deep.init(spec)
        for p in range(12):
            deep.set_samples(p, 1)
        self.assertTrue(out.write_deep_image(deep))
        out.close()
        with self.assertRaises(dataset.DatasetError) as e:
            dataset.read_exr(path)
        self.assertIn(f"{path}: deep data (several samples per pixel of varying count) is not "
                      f"read; flatten it first, e.g. oiiotool {path} --flatten -o flat.exr",
                      str(e.exception))

    def test_header_faults_refused_before_openimageio_reads_them(self):
        """A channel name that is not UTF-8, a pixel type OpenEXR does not
        know and a header cut short are refused naming the file and the
        fault, before OpenImageIO reads the header: its Python binding
        raised a bare UnicodeDecodeError on the first, and it aborted the
        process on some lists of the second. Read in a subprocess, so that
        an abort fails the test instead of ending it."""
        names = [f"S0.{f}" for f in dataset.FEATURES]
        path = os.path.join(self.work, "names.exr")
        dataset.write_exr(path, names, np.full((3, 4, 6), 0.5, np.float32))
        with open(path, "rb") as f:
            whole = f.read()
        at = whole.index(b"S0.depth\0")
        cases = [
            (whole[:at + 1] + b"\xff" + whole[at + 2:],
             'channel "S\ufffd.depth" of part 0 has a name that is not UTF-8'),
            (whole[:at + 9] + struct.pack("<i", 52738) + whole[at + 13:],
             'channel "S0.depth" of part 0 has pixel type 52738, not UINT (0), HALF (1) or '
             "FLOAT (2)"),
            (whole[:at + 4], "truncated / incomplete file: it ends inside its header"),
        ]
        code = ("import sys\n"
                f"sys.path.insert(0, {WEIGHTS!r})\n"
                "import dataset\n"
                "try:\n"
                "    dataset.read_exr(sys.argv[1])\n"
                "except dataset.DatasetError as e:\n"
                "    print(e)\n")
        for i, (blob, want) in enumerate(cases):
            bad = os.path.join(self.work, f"header_fault{i}.exr")
            with open(bad, "wb") as f:
                f.write(blob)
            r = subprocess.run([sys.executable, "-c", code, bad], capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn(f"{bad}: {want}", r.stdout)

    def test_uint_channels_read_as_their_integers(self):
        """A UINT channel reads as its integers converted to float, as
        OpenEXR and the C reader convert it, not scaled to [0, 1] as
        OpenImageIO presents it: training and hairfilter see one value."""
        import OpenImageIO as oiio
        ints = np.array([[[0, 1, 7, 4294967295]]], np.uint32)
        spec = oiio.ImageSpec(1, 1, 4, oiio.UINT32)
        spec.channelnames = ("c0", "c1", "c2", "c3")
        spec.channelformats = tuple(oiio.TypeDesc(t) for t in ("uint", "uint", "half", "uint"))
        path = os.path.join(self.work, "uint.exr")
        out = oiio.ImageOutput.create(path)
        self.assertTrue(out.open(path, spec) and out.write_image(ints), oiio.geterror())
        out.close()
        names, data = dataset.read_exr(path)
        self.assertEqual(names, ["c0", "c1", "c2", "c3"])
        self.assertEqual([float(data[0, 0, c]) for c in (0, 1, 3)],
                         [0.0, 1.0, float(np.float32(4294967295))])

    def test_augmentation_keeps_tangents_on_the_strand(self):
        """A single straight strand: after every flip/rotation the tangent
        features must still be parallel to the strand as seen in the image
        (its principal axis), for every augmentation draw."""
        h = w = 48
        f = np.zeros((h, w, 2, 6), np.float32)
        t = np.zeros((h, w, 3), np.float32)
        ang = 0.5  # radians, view space (y up)
        tx, ty = np.cos(ang), np.sin(ang)
        for s in np.linspace(-18, 18, 200):
            col = int(round(24 + s * tx))
            row = int(round(24 - s * ty))             # image rows go down
            f[row, col, :, 2] = 0.5
            f[row, col, :, 4], f[row, col, :, 5] = tx, ty
            t[row, col, 2] = 0.5
        rng = np.random.default_rng(0)
        seen = set()
        for _ in range(64):
            g, u = dataset.augment(f, t, rng)
            rows, cols = np.nonzero(g[..., 0, 2] > 0)
            self.assertTrue(np.array_equal(np.nonzero(u[..., 2] > 0), (rows, cols)))
            pts = np.stack([cols - cols.mean(), -(rows - rows.mean())], 1)  # view axes
            axis = np.linalg.svd(pts, full_matrices=False)[2][0]
            tan = g[rows[0], cols[0], 0, 4:6]
            self.assertGreater(abs(float(axis @ tan)), 0.99, "tangent off the strand")
            seen.add(tuple(np.round(tan, 3)))
        self.assertGreaterEqual(len(seen), 4, "augmentation produced too few orientations")

    def test_dim_light_scales_samples_target_and_estimate_alike(self):
        """dataset.dim_light: every sample's colour factor and the target's
        (and the estimate's) by one factor, the highlights by another drawn
        independently, both in [lo, 1] and drawn afresh per call; coverage,
        depth and tangents untouched; a bad lo refused, and so are
        --dim-light outside (0, 1] and --dim-share without it."""
        rng = np.random.default_rng(5)
        f = rng.uniform(0.1, 2.0, (6, 7, 4, 6)).astype(np.float32)
        f[0, 0] = 0                                  # a pixel without hair
        t = rng.uniform(0.1, 1.0, (6, 7, 6)).astype(np.float32)
        factors = set()
        for _ in range(8):
            g, u = dataset.dim_light(f, t, rng, 0.05)
            kc = g[..., dataset.COLOR] / np.where(f[..., 0] > 0, f[..., 0], 1)
            kh = g[..., dataset.HIGHLIGHT] / np.where(f[..., 1] > 0, f[..., 1], 1)
            kc, kh = float(kc[1, 1, 0]), float(kh[1, 1, 0])
            self.assertTrue(0.05 <= kc <= 1 and 0.05 <= kh <= 1, (kc, kh))
            np.testing.assert_allclose(g[..., 0], f[..., 0] * kc, rtol=1e-6)
            np.testing.assert_allclose(g[..., 1], f[..., 1] * kh, rtol=1e-6)
            np.testing.assert_array_equal(g[..., 2:], f[..., 2:])
            for base in (0, 3):
                np.testing.assert_allclose(u[..., base], t[..., base] * kc, rtol=1e-6)
                np.testing.assert_allclose(u[..., base + 1], t[..., base + 1] * kh, rtol=1e-6)
                np.testing.assert_array_equal(u[..., base + 2], t[..., base + 2])
            self.assertTrue((g[0, 0] == 0).all())
            factors.add((round(kc, 6), round(kh, 6)))
        self.assertEqual(len({kc for kc, _ in factors}), 8)
        self.assertEqual(len({kh for _, kh in factors}), 8)
        self.assertTrue(any(kc != kh for kc, kh in factors))
        for bad in (0.0, 1.5):
            with self.assertRaises(ValueError):
                dataset.dim_light(f, t, rng, bad)
        for bad in (["--dim-light", "-0.1"], ["--dim-light", "2"], ["--dim-share", "0.3"],
                    ["--dim-light", "0.1", "--dim-share", "1.5"]):
            with self.assertRaises(SystemExit):
                train.parse_args(["--out", "x", *bad])
        self.assertEqual(train.parse_args(["--out", "x", "--dim-light", "0.1"]).dim_share, 0.5)

    def test_deconv_rewrite_is_exact(self):
        torch.manual_seed(0)
        for name in ("Base", "Shallow", "Deep", "Kernel"):
            net = hfnet.HairNet(hfnet.variant_config(name))
            x = torch.randn(2, net.cfg["in_channels"], 32, 48)
            with torch.no_grad():
                a, b = net.raw(x), train.raw_shuffle(net, x)
            self.assertLess(float((a - b).abs().max()), 1e-5, name)

    def test_equal_phase_sums_keep_a_flat_input_flat(self):
        """hfnet.equalise_phase_sums_: a random U-Net paints a lattice on a
        constant input; projected, its interior output is constant, each
        phase of each kernel moved by one amount, and a second projection
        moves nothing. --equal-phase-sums keeps trained weights there."""
        torch.manual_seed(4)

        def spread(net, x):
            with torch.no_grad():
                y = net.raw(x)[..., 16:48, 16:48]      # away from the zero padding
            return float((y - y.mean((-2, -1), keepdim=True)).abs().max())

        def phase_sums(w):
            return torch.stack([w[..., a::2, b::2].sum((-2, -1)) for a in (0, 1) for b in (0, 1)])

        for name in ("Shallow", "Base", "Kernel"):
            net = hfnet.HairNet(hfnet.variant_config(name))
            x = torch.rand(1, net.cfg["in_channels"], 1, 1).expand(1, -1, 64, 64).contiguous()
            self.assertGreater(spread(net, x), 1e-3, name)
            before = {k: v.clone() for k, v in net.state_dict().items()}
            self.assertGreater(hfnet.equalise_phase_sums_(net), 1e-3, name)
            self.assertLess(spread(net, x), 1e-5, name)
            self.assertLess(hfnet.equalise_phase_sums_(net), 1e-6, name)
            for k, v in net.state_dict().items():
                if k.startswith("dec") and k.endswith("weight"):
                    d = v - before[k]
                    for a in (0, 1):
                        for b in (0, 1):
                            ph = d[..., a::2, b::2]
                            self.assertLess(float((ph - ph[..., :1, :1]).abs().max()), 1e-6)
                else:
                    self.assertTrue(torch.equal(v, before[k]), k)
        out = os.path.join(self.work, "phases")
        run_train("--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "3", "--steps", "3", "--equal-phase-sums", "--out", out,
                  "--export", out + ".safetensors")
        _, state = hfnet.load_safetensors(out + ".safetensors")
        for k, w in state.items():
            if k.startswith("dec") and k.endswith("weight"):
                s = phase_sums(w)
                self.assertLess(float((s - s.mean(0)).abs().max()), 1e-5, k)
        with open(os.path.join(out, "summary.json")) as f:
            self.assertTrue(json.load(f)["equal_phase_sums"])

    def test_kernel_softmax_leaves_the_outside_out(self):
        """Taps outside the frame count for nothing whatever their logits: a
        huge one must neither change the result nor make it NaN (it would
        underflow every weight inside the frame were it the maximum)."""
        torch.manual_seed(2)
        x = torch.rand(1, 24, 9, 7) * (torch.rand(1, 24, 9, 7) > 0.3)
        raw = torch.randn(1, 25 + 3, 9, 7, requires_grad=True)
        y = hfnet.kernel_finish(raw, x, 4, 2)
        y.sum().backward()
        self.assertTrue(bool(torch.isfinite(raw.grad).all()))
        big = raw.detach().clone()
        big[:, 0, 0, :] = 1e4        # tap (-2, -2): outside for row 0
        big[:, 24, :, 6] = 1e4       # tap (2, 2): outside for column 6
        y2 = hfnet.kernel_finish(big, x, 4, 2)
        self.assertTrue(bool(torch.isfinite(y2).all()))
        self.assertTrue(torch.equal(y2, y.detach()))

    def test_widening_kernel_hidden_keeps_the_function(self):
        """--init of a Kernel net into one with more hidden channels: the
        wider net computes what the narrower did, and the new channels are
        trainable (their head weights get gradient)."""
        torch.manual_seed(4)
        cfg = hfnet.variant_config("Kernel")
        narrow = hfnet.HairNet(cfg)
        wide_cfg = dict(cfg, kernel_hidden=cfg["kernel_hidden"] * 2)
        wide = hfnet.HairNet(wide_cfg)
        wide.load_state_dict(hfnet.widen_kernel_hidden(narrow.state_dict(), cfg["kernel_hidden"],
                                                       wide.state_dict()))
        x = torch.rand(2, cfg["in_channels"], 24, 40) * (torch.rand(2, 1, 24, 40) > 0.2)
        with torch.no_grad():
            a, b = narrow(x), wide(x)
        self.assertLess(float((a - b).abs().max()), 1e-5)
        wide(x).sum().backward()
        new = wide.head.weight.grad[:, cfg["kernel_hidden"]:2 * cfg["kernel_hidden"]]
        self.assertGreater(float(new.abs().sum()), 0.0)

    def test_widening_levels_keeps_the_function(self):
        """--init of narrower weights into --levels: for a U-Net (Base) and
        a Kernel net the wider body computes what the narrower did, its new
        channels are trainable (the layers that read them get gradient), and
        a narrowing or a change in the number of levels is refused."""
        for variant, levels in (("Base", [40, 80, 160]), ("Kernel", [48, 96, 192])):
            torch.manual_seed(5)
            cfg = hfnet.variant_config(variant)
            narrow = hfnet.HairNet(cfg)
            wide = hfnet.HairNet(dict(cfg, levels=levels))
            wide.load_state_dict(hfnet.widen_levels(narrow.state_dict(), cfg["levels"],
                                                    wide.state_dict()))
            x = torch.rand(2, cfg["in_channels"], 24, 40) * (torch.rand(2, 1, 24, 40) > 0.2)
            with torch.no_grad():
                a, b = narrow(x), wide(x)
            self.assertLess(float((a - b).abs().max()), 1e-5, variant)
            wide(x).sum().backward()
            lo = cfg["levels"][0]
            new_in = wide.enc1.weight.grad[:, lo:]          # enc1 reading enc0's new channels
            self.assertGreater(float(new_in.abs().sum()), 0.0, variant)
            with self.assertRaises(ValueError):
                hfnet.widen_levels(wide.state_dict(), levels, narrow.state_dict())
            deep = hfnet.HairNet(dict(cfg, levels=levels + [256]))
            with self.assertRaises(ValueError):
                hfnet.widen_levels(narrow.state_dict(), cfg["levels"], deep.state_dict())

    def test_growing_the_kernel_radius(self):
        """--init of a smaller kernel_radius: with and without a head, the
        regrown net's logits are the old ones at the old taps and the
        nearest old border tap's less the drop at the new ones, its
        corrections are the old ones, a drop that underflows the new taps'
        weights gives the same function, and shrinking is refused."""
        for hidden in (32, 0):
            torch.manual_seed(7)
            cfg = dict(hfnet.variant_config("Kernel"), kernel_hidden=hidden)
            small = hfnet.HairNet(cfg)
            cfg4 = dict(cfg, kernel_radius=4, out_channels=hfnet.kernel_taps(4) + 3)
            big = hfnet.HairNet(cfg4)
            big.load_state_dict(hfnet.grow_kernel_radius(small.state_dict(), 3, 4, hidden))
            x = torch.rand(2, cfg["in_channels"], 24, 40) * (torch.rand(2, 1, 24, 40) > 0.2)
            with torch.no_grad():
                r3, r4 = small.raw(x), big.raw(x)
            for t, (dy, dx) in enumerate(hfnet._taps(4)):
                cy, cx = max(-3, min(3, dy)), max(-3, min(3, dx))
                s = (cy + 3) * 7 + cx + 3
                drop = 0.0 if (cy, cx) == (dy, dx) else 4.0
                self.assertLess(float((r4[:, t] - (r3[:, s] - drop)).abs().max()), 1e-5,
                                (hidden, dy, dx))
            self.assertLess(float((r4[:, 81:] - r3[:, 49:]).abs().max()), 1e-5, hidden)
            exact = hfnet.HairNet(cfg4)
            exact.load_state_dict(hfnet.grow_kernel_radius(small.state_dict(), 3, 4, hidden,
                                                           logit_drop=1e4))
            with torch.no_grad():
                self.assertLess(float((exact(x) - small(x)).abs().max()), 1e-5, hidden)
                self.assertGreater(float((big(x) - small(x)).abs().max()), 0.0, hidden)
            with self.assertRaises(ValueError):
                hfnet.grow_kernel_radius(big.state_dict(), 4, 3, hidden)

    @staticmethod
    def kernel_and_frame(seed, shared_fragment=False):
        """(cfg, a random Kernel network, a 2x24x40 frame with 30% of its
        samples uncovered, the network's result) for the experiments of
        weights/experiments/, which that folder on sys.path lets tests
        import; shared_fragment: sample 1 shows sample 0's fragment."""
        sys.path.insert(0, os.path.join(WEIGHTS, "experiments"))
        torch.manual_seed(seed)
        cfg = hfnet.variant_config("Kernel")
        kernel = hfnet.HairNet(cfg)
        x = torch.rand(2, cfg["in_channels"], 24, 40)
        alpha = x[:, 2::6]
        alpha[torch.rand_like(alpha) < 0.3] = 0
        if shared_fragment:
            s = x.view(2, 4, 6, 24, 40)
            s[:, 1, :3] = s[:, 0, :3]
        with torch.no_grad():
            want = kernel(x)
        return cfg, kernel, x, want

    def test_experimental_kernel_stages_start_as_the_kernel(self):
        """weights/experiments/kernel_stages.py: either stage, from Kernel
        weights with the second logits a copy of the first, computes what
        the Kernel did; the frontback stage tags as front exactly the
        samples that show the nearest fragment."""
        # Two samples of each pixel show the same fragment as the first.
        cfg, kernel, x, want = self.kernel_and_frame(5, shared_fragment=True)
        import kernel_stages
        s = x.view(2, 4, 6, 24, 40)
        try:
            for stage in kernel_stages.STAGES:
                kernel_stages.install(stage)
                c2, st2 = kernel_stages.start_from_kernel(cfg, kernel.state_dict())
                net = hfnet.HairNet(c2)
                net.load_state_dict(st2)
                with torch.no_grad():
                    got = net(x)
                self.assertLess(float((got - want).abs().max()), 1e-4, stage)
        finally:
            kernel_stages.uninstall()
        sums = kernel_stages.front_back_sums(x, 4)
        cov = s[:, :, 2] > 0
        depth = torch.where(cov, s[:, :, 3], torch.full_like(s[:, :, 3], float("inf")))
        near = depth.argmin(1)
        for n, y, xx in ((0, 3, 5), (1, 10, 20), (0, 23, 39)):
            k = int(near[n, y, xx])
            front = [j for j in range(4) if cov[n, j, y, xx]
                     and bool((s[n, j, :3, y, xx] == s[n, k, :3, y, xx]).all())]
            self.assertEqual(float(sums[n, 3, y, xx]), len(front))
            self.assertAlmostEqual(float(sums[n, 4, y, xx]),
                                   float(sum(s[n, j, 0, y, xx] for j in front)), places=5)
        self.assertEqual(hfnet.variant_config("Kernel")["out_channels"], cfg["out_channels"])

    def test_experimental_aniso_kernel(self):
        """weights/experiments/aniso_kernel.py: at a vanishing kappa the
        stage computes what the Kernel did; a tap's penalty is its squared
        distance from the line of the pixel's screen tangents (y down), half
        its squared length where they point every way, and its squared
        length where no sample is covered."""
        cfg, kernel, x, want = self.kernel_and_frame(7)
        import aniso_kernel
        try:
            aniso_kernel.install()
            c2, st2 = aniso_kernel.start_from_kernel(cfg, kernel.state_dict(), kappa0=1e-9)
            net = hfnet.HairNet(c2)
            net.load_state_dict(st2)
            with torch.no_grad():
                got = net(x)
            self.assertLess(float((got - want).abs().max()), 1e-5)
        finally:
            aniso_kernel.uninstall()
        r, taps = 3, hfnet.kernel_taps(3)
        f = torch.zeros(1, 4, 6, 1, 3)
        f[0, :, 2] = 0.5                                    # every sample covered
        # Pixel 0: view tangent (1, 1), on screen down-left to up-right.
        f[0, :, 4, 0, 0], f[0, :, 5, 0, 0] = 0.6, 0.6
        # Pixel 1: two samples along x, two along y.
        f[0, :2, 4, 0, 1], f[0, 2:, 5, 0, 1] = 0.9, -0.9
        f[0, :, 2, 0, 2] = 0                                # pixel 2: nothing covered
        raw = torch.zeros(1, taps + 4, 1, 3)
        raw[0, taps + 3] = 1e9                              # kappa = GAIN * 1e9
        kappa = aniso_kernel.GAIN * 1e9
        pen = -aniso_kernel.aniso_logits(raw, f.view(1, 24, 1, 3), 4, r)[0] / kappa
        for t, (dy, dx) in enumerate(hfnet._taps(r)):
            # Unit direction (1, -1) / sqrt(2) in (x, y-down).
            self.assertAlmostEqual(float(pen[t, 0, 0]), (dx + dy) ** 2 / 2, places=4)
            self.assertAlmostEqual(float(pen[t, 0, 1]), (dx * dx + dy * dy) / 2, places=4)
            self.assertAlmostEqual(float(pen[t, 0, 2]), dx * dx + dy * dy, places=4)

    def test_kernel_mix_starts_from_kernel_ac(self):
        """hfnet.add_kernel_mix: KernelAC weights with the mixing output
        added at a vanishing beta make a KernelMix network that computes
        what KernelAC did, with and without a head; kernel_finish_mixed at
        beta 1 filters the samples' own sums with the same kernel, and
        between the two mixes the aggregated sums linearly."""
        torch.manual_seed(11)
        for hidden in (32, 0):
            cfg = dict(hfnet.variant_config("KernelAC"), kernel_hidden=hidden)
            kac = hfnet.HairNet(cfg)
            x = torch.rand(2, cfg["in_channels"], 24, 40)
            alpha = x[:, 2:24:6]
            alpha[torch.rand_like(alpha) < 0.3] = 0
            with torch.no_grad():
                want = kac(x)
            mcfg = dict(hfnet.variant_config("KernelMix"), kernel_hidden=hidden)
            self.assertEqual(mcfg["out_channels"], cfg["out_channels"] + 1)
            net = hfnet.HairNet(mcfg)
            net.load_state_dict(hfnet.add_kernel_mix(kac.state_dict(), hidden, beta0=1e-9))
            with torch.no_grad():
                got = net(x)
            self.assertLess(float((got - want).abs().max()), 1e-5, hidden)
        taps = hfnet.kernel_taps(3)
        with torch.no_grad():
            raw = kac.raw_any_size(x)
            for m, beta in ((1e9, 1.0), (0.0, 0.5)):
                r4 = torch.cat([raw, torch.full_like(raw[:, :1], m)], 1)
                got = hfnet.kernel_finish_mixed(r4, x, 4, 3)
                sums = beta * hfnet.pixel_sums(x, 4) + (1 - beta) * hfnet.estimate_sums(x, 4)
                exp = hfnet.kernel_finish_sums(raw, sums, 4, 3)
                self.assertLess(float((got - exp).abs().max()), 1e-5, beta)
            self.assertGreater(float((hfnet.kernel_finish_sums(raw, hfnet.pixel_sums(x, 4), 4, 3)
                                      - want).abs().max()), 1e-3)
        with self.assertRaises(ValueError) as e:
            hfnet.check_config("x", dict(hfnet.variant_config("Kernel"), kernel_mix=1,
                                         out_channels=taps + 4))
        self.assertIn("kernel_mix", str(e.exception))

    def test_experiment_weights_load_with_the_experiment(self):
        """hfnet.load_safetensors reads, with its experiment installed, a
        file whose Kernel has that experiment's outputs (aniso_kernel.py
        init's, which `aniso_kernel.py train --init` loads: it was refused
        for its out_channels); without the experiment it is refused."""
        cfg, kernel, _, _ = self.kernel_and_frame(8)
        import aniso_kernel
        path = os.path.join(self.work, "aniso_init.safetensors")
        try:
            aniso_kernel.install()
            c2, st2 = aniso_kernel.start_from_kernel(cfg, kernel.state_dict())
            hfnet.save_safetensors(path, c2, st2)
            c3, st3 = hfnet.load_safetensors(path)
            self.assertEqual(c3["out_channels"], hfnet.kernel_taps(3) + 4)
            self.assertEqual(sorted(st3), sorted(st2))
        finally:
            aniso_kernel.uninstall()
        with self.assertRaises(ValueError) as e:
            hfnet.load_safetensors(path)
        self.assertIn("out_channels", str(e.exception))

    def test_experimental_sorted_samples(self):
        """weights/experiments/sorted_samples.py: each pixel's samples come
        nearest first, uncovered last in slot order, and the network so
        built gives the same result whatever the order of the sample slots
        (and the weights of a plain Kernel load unchanged)."""
        cfg, kernel, x, _ = self.kernel_and_frame(9)
        import sorted_samples
        f = torch.zeros(1, 4, 6, 1, 1)
        f[0, :, 2, 0, 0] = torch.tensor([0.5, 0.0, 0.5, 0.5])    # slot 1 uncovered
        f[0, :, 3, 0, 0] = torch.tensor([0.7, 0.1, 0.2, 0.9])    # depths
        f[0, :, 0, 0, 0] = torch.tensor([1.0, 2.0, 3.0, 4.0])    # colours name the slots
        got = sorted_samples.sort_samples(f.view(1, 24, 1, 1), 4).view(1, 4, 6)
        self.assertEqual(got[0, :, 0].tolist(), [3.0, 1.0, 4.0, 2.0])
        try:
            sorted_samples.install()
            net = hfnet.HairNet(cfg)
            net.load_state_dict(kernel.state_dict())
            # Uncovered samples all zeros, as the renderer writes them.
            s = x.view(2, 4, 6, *x.shape[-2:]).clone()
            s *= (s[:, :, 2:3] > 0)
            x = s.reshape(x.shape)
            with torch.no_grad():
                want = kernel(x)
            perm = s[:, [2, 0, 3, 1]].reshape(x.shape)
            with torch.no_grad():
                a, b = net(x), net(perm)
            self.assertLess(float((a - b).abs().max()), 1e-5)
            self.assertGreater(float((a - want).abs().max()), 0.0)
        finally:
            sorted_samples.uninstall()

    def test_experimental_alpha_corrected_input(self):
        """weights/experiments/ac_input.py: Kernel weights started on the
        estimate keep the Kernel's raw output whatever the estimate, and
        when the estimate is each pixel's own 4-sample estimate the output
        stage is Kernel's exactly; augmentation keeps the estimate last; a
        frame without acst4.* is refused with the option that makes it."""
        cfg, kernel, x, want = self.kernel_and_frame(10)
        import ac_input
        s = x.view(2, 4, 6, *x.shape[-2:])
        cov = (s[:, :, 2] > 0).float()
        n = cov.sum(1)
        slot = torch.zeros(2, 6, *x.shape[-2:])
        slot[:, 0] = torch.where(n > 0, (s[:, :, 0] * cov).sum(1) / n.clamp(min=1), 0 * n)
        slot[:, 1] = torch.where(n > 0, (s[:, :, 1] * cov).sum(1) / n.clamp(min=1), 0 * n)
        slot[:, 2] = n / 4
        xa = torch.cat([x, slot], 1)
        try:
            ac_input.install()
            acfg, state = ac_input.start_from_kernel(cfg, kernel.state_dict())
            self.assertEqual((acfg["spp"], acfg["in_channels"]), (5, 30))
            net = hfnet.HairNet(acfg)
            net.load_state_dict(state)
            other = xa.clone()
            other[:, 24:27] = torch.rand(2, 3, *x.shape[-2:])
            with torch.no_grad():
                self.assertLess(float((net.raw(other) - kernel.raw(x)).abs().max()), 1e-5)
                got = net(xa)
            self.assertLess(float((got - want).abs().max()), 1e-4)
            # Exported as KernelAC (the slot's zero inputs dropped): the
            # same output from the samples and the estimate's 3 channels.
            vcfg, vstate = ac_input.to_variant(acfg, state)
            self.assertEqual((vcfg["name"], vcfg["in_channels"], vcfg["estimate"]),
                             ("KernelAC", 27, "alpha_corrected"))
            ac_input.uninstall()
            vnet = hfnet.HairNet(vcfg)
            vnet.load_state_dict(vstate)
            with torch.no_grad():
                self.assertEqual(float((vnet(xa[:, :27]) - got).abs().max()), 0.0)
            ac_input.install()
            f = np.random.default_rng(0).random((8, 8, 5, 6)).astype(np.float32)
            f[:, :, 4, :3] += 100
            for seed in range(4):
                g, _ = dataset.augment(f, np.zeros((8, 8, 3), np.float32),
                                       np.random.default_rng(seed))
                self.assertTrue((g[:, :, 4, :3] >= 100).all())
                self.assertTrue((g[:, :, :4, :3] < 1).all())
            with tempfile.TemporaryDirectory() as d:
                p = os.path.join(d, "f.exr")
                names = [f"S{k}.{c}" for k in range(4) for c in hfnet.FEATURES] + \
                    ["gt.color", "gt.highlight", "gt.alpha"]
                dataset.write_exr(p, names, np.zeros((4, 4, len(names)), np.float32))
                with self.assertRaisesRegex(dataset.DatasetError, "--alpha-corrected"):
                    dataset.load_frame(p)
        finally:
            ac_input.uninstall()
        self.assertEqual(hfnet.variant_config("Kernel")["spp"], 4)

    def test_experimental_ac_grid(self):
        """weights/experiments/ac_grid.py: one row per frame of five crops
        with gaps, the composite of an opaque result is the hair colour
        (sRGB), and a crop that leaves the frame is refused."""
        sys.path.insert(0, os.path.join(WEIGHTS, "experiments"))
        import ac_grid
        names = [f"{p}.{k}" for p in ac_grid.COLUMNS for k in ("color", "highlight", "alpha")]
        data = np.zeros((8, 10, len(names)), np.float32)
        for p in ac_grid.COLUMNS:
            data[..., names.index(f"{p}.color")] = 1.0
            data[..., names.index(f"{p}.alpha")] = 1.0
        with tempfile.TemporaryDirectory() as d:
            f, out = os.path.join(d, "f.exr"), os.path.join(d, "g.png")
            dataset.write_exr(f, names, data)
            self.assertEqual(ac_grid.main([out, f + ":1,0,6", f + ":4,2,6"]), 0)
            img = OpenImageIO.ImageBuf(out)
            self.assertEqual((img.spec().width, img.spec().height),
                             (5 * 6 + 4 * ac_grid.GAP, 2 * 6 + ac_grid.GAP))
            px = np.asarray(img.get_pixels(OpenImageIO.FLOAT))[0, 0]
            want = ac_grid.srgb(ac_grid.HAIR)
            self.assertLess(float(np.abs(px - want).max()), 1.5 / 255)
            with self.assertRaises(SystemExit):
                ac_grid.main([out, f + ":6,0,6"])

    def test_experimental_fullres_branch_starts_as_the_kernel(self):
        """weights/experiments/fullres_branch.py: Kernel weights with the
        branch added compute what the Kernel did, the head's new columns
        get a gradient (so training grows the branch), and uninstall gives
        hfnet its plain network back."""
        cfg, kernel, x, want = self.kernel_and_frame(6)
        import fullres_branch
        try:
            fullres_branch.install(8)
            self.assertEqual(hfnet.variant_config("Kernel")["fullres"], 8)
            c2, st2 = fullres_branch.start_from_kernel(cfg, kernel.state_dict(), channels=8)
            net = hfnet.HairNet(c2)
            net.load_state_dict(st2)
            self.assertEqual(tuple(net.full.weight.shape), (8, cfg["in_channels"], 3, 3))
            with torch.no_grad():
                got = net(x)
            self.assertLess(float((got - want).abs().max()), 1e-5)
            net(x).square().sum().backward()
            new = net.head.weight.grad[:, cfg["kernel_hidden"] + cfg["in_channels"]:]
            self.assertGreater(float(new.abs().sum()), 0.0)
        finally:
            fullres_branch.uninstall()
        self.assertIs(hfnet.HairNet, fullres_branch._HairNet)
        self.assertNotIn("fullres", hfnet.variant_config("Kernel"))

    def test_experimental_base_carry_holds_each_pixel(self):
        """weights/experiments/base_carry.py: its taps read dec0's output
        as the transposed convolution computes it; after the graft the 12
        carry channels of enc0 hold each pixel's sample means of colour,
        highlight and alpha; the colour's inverse undoes the paper's cubic;
        and a dec0 refit against targets dec0 can make reproduces them."""
        sys.path.insert(0, os.path.join(WEIGHTS, "experiments"))
        import base_carry
        import torch.nn.functional as F
        torch.manual_seed(11)
        z, w, b = torch.randn(2, 5, 6, 7), torch.randn(5, 3, 4, 4), torch.randn(3)
        y = F.conv_transpose2d(z, w, b, stride=2, padding=1)
        for a in (0, 1):
            for c in (0, 1):
                d, taps = base_carry.design(z, a, c)
                wt = torch.cat([w[:, :, ky, kx] for ky, kx in taps]).double().numpy()
                got = d @ wt + b.double().numpy()
                want = y[:, :, a::2, c::2].permute(0, 2, 3, 1).double().numpy()
                self.assertLess(float(np.abs(got - want).max()), 1e-4, (a, c))

        col = np.linspace(0.0, 2.5, 11)
        x = torch.from_numpy(base_carry.color_preactivation(col)).float().view(1, 1, 1, -1)
        back = hfnet.output_transform(torch.cat([x, x, x], 1))[0, 0, 0].double().numpy()
        self.assertLess(float(np.abs(back - col).max()), 1e-5)

        cfg = hfnet.variant_config("Base")
        net = hfnet.HairNet(cfg)
        feats = torch.rand(2, cfg["in_channels"], 32, 32)
        truth = torch.rand(2, 3, 32, 32)
        chosen, _ = base_carry.graft(net, [(feats, truth)], 12, cfg["spp"])
        self.assertEqual(len(set(chosen)), 12)
        with torch.no_grad():
            _, enc0 = base_carry.decoder_input(net, feats)
        s = feats.view(2, cfg["spp"], 6, 32, 32).mean(1)            # [n][feature][h][w]
        for k, ch in enumerate(chosen):
            pix, f = divmod(k, 3)
            a, c = divmod(pix, 2)
            want = s[:, base_carry.CARRIED[f], a::2, c::2]
            self.assertLess(float((enc0[:, ch] - want).abs().max()), 1e-5, (k, ch))
            self.assertEqual(float(net.enc1.weight[:, ch].abs().sum()), 0.0)

        # Targets dec0 can make exactly, inside every clamp: the refit finds them.
        with torch.no_grad():
            zin, _ = base_carry.decoder_input(net, feats)
            r0 = F.conv_transpose2d(zin, net.dec0.weight, None, stride=2, padding=1)
            net.dec0.weight.mul_(0.4 / float(r0.abs().max()))
            net.dec0.bias.copy_(torch.tensor([0.0, 0.5, 0.5]))
            raw = F.conv_transpose2d(zin, net.dec0.weight, net.dec0.bias, stride=2, padding=1)
            target = hfnet.output_transform(raw)
            net.dec0.weight.normal_()
            net.dec0.bias.zero_()
        self.assertTrue(bool(((raw[:, 1:] > 0) & (raw[:, 2:] < 1)).all()))
        base_carry.refit_dec0(net, [(feats, target)], ridge=1e-9)
        with torch.no_grad():
            got = net.raw(feats)
        self.assertLess(float((got - raw).abs().max()), 1e-3)

    def test_kernel_export_roundtrips(self):
        """A Kernel network (head and metadata keys) and one without a head
        go through the C loader and writer bit-exactly."""
        for radius, hidden in ((3, 16), (2, 0)):
            cfg = hfnet.variant_config("Kernel")
            cfg.update(kernel_radius=radius, kernel_hidden=hidden,
                       out_channels=hfnet.kernel_taps(radius) + 3)
            torch.manual_seed(radius)
            net = hfnet.HairNet(cfg)
            self.assertEqual(hasattr(net, "head"), hidden > 0)
            exp = os.path.join(self.work, f"kernel{radius}.safetensors")
            back = os.path.join(self.work, f"kernel{radius}_back.safetensors")
            hfnet.save_safetensors(exp, cfg, net.state_dict())
            subprocess.run([ARGS.roundtrip, exp, back], check=True, capture_output=True)
            cfg_b, sd_b = hfnet.load_safetensors(back)
            for k in ("arch", "kernel_radius", "kernel_hidden", "out_channels"):
                self.assertEqual(cfg_b[k], cfg[k], k)
            sd_a = net.state_dict()
            self.assertEqual(sorted(sd_a), sorted(sd_b))
            for k in sd_a:
                self.assertTrue(torch.equal(sd_a[k], sd_b[k]), k)

    def test_bf16_path_is_close(self):
        torch.manual_seed(1)
        net = hfnet.HairNet(hfnet.variant_config("Base"))
        x = torch.rand(1, 24, 64, 64)
        with torch.no_grad():
            a = train.forward(net, x, "transpose", False)
            b = train.forward(net, x, "shuffle", True)
        rel = float((a - b).norm() / a.norm())
        self.assertLess(rel, 2e-2)

    def test_straight_through_clamps_revive_a_dead_channel(self):
        """A highlight output pushed below zero (dead under the exact clamp,
        the failure the straight-through clamps exist for) must get a
        gradient back towards the target; values stay those of the exact
        transforms, for both architectures."""
        torch.manual_seed(0)
        for variant in ("Shallow", "Residual"):
            net = hfnet.HairNet(hfnet.variant_config(variant))
            x = torch.rand(1, net.cfg["in_channels"], 16, 16)
            with torch.no_grad():
                net.dec0.bias[1] = -50.0
            y = torch.zeros(1, 3, 16, 16)
            y[:, 1], y[:, 2] = 0.5, 1.0            # highlight wanted everywhere
            grads = {}
            for st in (False, True):
                net.zero_grad()
                out = train.forward(net, x, "transpose", False, straight_through=st)
                self.assertTrue(torch.equal(out, net(x)))
                self.assertEqual(float(out[:, 1].max()), 0.0)
                train.hair_loss(out, y).backward()
                grads[st] = float(net.dec0.bias.grad[1])
            self.assertEqual(grads[False], 0.0, variant)
            self.assertLess(grads[True], 0.0, variant)   # descent raises the bias

    def test_loss_is_the_papers(self):
        """Premultiplied MSE plus gradient MSE, checked on a hand example."""
        p = torch.zeros(1, 3, 2, 2)
        q = torch.zeros(1, 3, 2, 2)
        q[0, 2, 0, 0] = 1.0            # alpha 1 at one pixel
        q[0, 0, 0, 0] = 2.0            # color 2 there -> premultiplied 2
        # MSE: (4 + 1) / 12; dx: pixel (0,0)-(0,1) differs in 2 channels:
        # (4 + 1) / 6; dy likewise (4 + 1) / 6.
        want = 5 / 12 + 5 / 6 + 5 / 6
        self.assertAlmostEqual(float(train.hair_loss(p, q, 1.0)), want, places=6)
        q2 = q.clone()
        q2[0, 0, 1, 1] = 7.0           # color where alpha = 0 does not count
        self.assertAlmostEqual(float(train.hair_loss(p, q2, 1.0)), want, places=6)

    def test_look_loss_is_what_a_viewer_sees(self):
        """The look loss composites as hf_composite and `hairfilter eval` do
        (clamped to [0, 1]) and weighs each channel as the image shows it."""
        hair, light, bg = train.eval_looks(1, "cpu")
        y = torch.tensor([1.5, 0.2, 0.5]).view(1, 3, 1, 1)
        want = [min(1.0, 0.5 * (h * 1.5 + 0.2) + 0.5 * b)
                for h, b in zip(train.EVAL_LOOK[0], train.EVAL_LOOK[2])]
        got = train.composite(y, hair, light, bg).flatten().tolist()
        for g, w in zip(got, want):
            self.assertAlmostEqual(g, w, places=6)
        bright = torch.tensor([1.0, 5.0, 1.0]).view(1, 3, 1, 1)
        self.assertEqual(train.composite(bright, hair, light, bg).max().item(), 1.0)
        # Alone (no paper term, no gradients), an error of 0.1 in the
        # highlight of an opaque pixel costs 0.1^2 in every channel; the same
        # error in the colour factor costs 0.1^2 times the hair colour's
        # mean square, and nothing at all where alpha is 0.
        t = torch.tensor([1.0, 0.1, 1.0]).view(1, 3, 1, 1)
        looks = (hair, light, bg)
        hl = train.look_loss(t + torch.tensor([0, 0.1, 0]).view(1, 3, 1, 1), t, looks, 0, 0)
        col = train.look_loss(t + torch.tensor([0.1, 0, 0]).view(1, 3, 1, 1), t, looks, 0, 0)
        self.assertAlmostEqual(float(hl), 0.01, places=6)
        self.assertAlmostEqual(float(col), 0.01 * sum(h * h for h in train.EVAL_LOOK[0]) / 3,
                               places=6)
        clear = torch.tensor([1.0, 0.1, 0.0]).view(1, 3, 1, 1)
        self.assertEqual(float(train.look_loss(clear + 0.3 * (torch.arange(3) < 2).view(1, 3, 1, 1),
                                               clear, looks, 0, 0)), 0.0)
        # The paper's term is added with its weight.
        t = torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(5))
        p = t + 0.1 * torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(6))
        self.assertAlmostEqual(float(train.look_loss(p, t, looks, 1.0, 0.1)),
                               float(train.look_loss(p, t, looks, 1.0, 0))
                               + 0.1 * float(train.hair_loss(p, t, 1.0)), places=6)
        # Random looks: hair colours inside [0, 1], one look per crop.
        h, li, b = train.random_looks(64, torch.Generator().manual_seed(3))
        self.assertEqual(tuple(h.shape), (64, 3, 1, 1))
        self.assertTrue(bool((h >= 0).all() and (h <= 1).all() and (b >= 0).all()))
        self.assertGreater(float(h.std(0).min()), 0.05)

    def test_display_straight_through_pulls_a_black_pixel_back(self):
        """An opaque, dark pixel whose colour factor has gone below 0 shows
        black (the composite is clamped at 0): the look loss's value is the
        same with display_st, but only with it does the colour factor get a
        gradient, and one that raises it towards the truth; a pixel inside
        [0, 1] gets the same gradient either way; --display-straight-through
        needs the look loss."""
        looks = train.eval_looks(1, "cpu")
        t = torch.tensor([0.03, 0.0, 1.0]).view(1, 3, 1, 1)
        grads = {}
        for st in (False, True):
            for name, c in (("black", -0.05), ("dark", 0.01)):
                p = torch.tensor([c, 0.0, 1.0]).view(1, 3, 1, 1).requires_grad_()
                loss = train.look_loss(p, t, looks, 0, 0, display_st=st)
                loss.backward()
                grads[st, name] = (float(loss), float(p.grad[0, 0]))
        self.assertEqual(grads[False, "black"][0], grads[True, "black"][0])
        self.assertGreater(grads[False, "black"][0], 0)
        self.assertEqual(grads[False, "black"][1], 0.0)
        self.assertLess(grads[True, "black"][1], 0.0)   # descent raises the colour factor
        self.assertEqual(grads[False, "dark"], grads[True, "dark"])
        self.assertLess(grads[True, "dark"][1], 0.0)
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", "--display-straight-through"])

    def test_look_srgb_weighs_dark_errors_as_a_display_shows_them(self):
        """srgb_encode is the sRGB transfer function (IEC 61966-2-1: 12.92 x
        below 0.0031308, 1.055 x^(1/2.4) - 0.055 above; 0.5 encodes to
        0.7354), and with srgb the look loss is the MSE of the encoded
        composites: the same error of 0.01 in the colour factor of an opaque
        pixel costs more in dark hair than in bright hair, where the linear
        loss costs both alike; --look-srgb needs the look loss."""
        x = torch.tensor([0.0, 0.002, 0.0031308, 0.5, 1.0])
        want = [0.0, 12.92 * 0.002, 12.92 * 0.0031308, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0]
        for g, w in zip(train.srgb_encode(x).tolist(), want):
            self.assertAlmostEqual(g, w, places=5)
        self.assertAlmostEqual(float(train.srgb_encode(torch.tensor(0.5))), 0.7354, places=4)
        looks = train.eval_looks(1, "cpu")
        cost = {}
        for srgb in (False, True):
            for name, c in (("dark", 0.05), ("bright", 0.9)):
                t = torch.tensor([c, 0.0, 1.0]).view(1, 3, 1, 1)
                p = t + torch.tensor([0.01, 0.0, 0.0]).view(1, 3, 1, 1)
                cost[srgb, name] = float(train.look_loss(p, t, looks, 0, 0, srgb=srgb))
        self.assertAlmostEqual(cost[False, "dark"], cost[False, "bright"], places=9)
        self.assertGreater(cost[True, "dark"], 4 * cost[True, "bright"])
        hair = torch.tensor(train.EVAL_LOOK[0])
        enc = train.srgb_encode
        want = float(((enc(hair * 0.06) - enc(hair * 0.05)) ** 2).mean())
        self.assertAlmostEqual(cost[True, "dark"], want, places=9)
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", "--look-srgb"])

    def test_look_l1_takes_the_median_of_an_ambiguous_target(self):
        """l1_and_gradients is the mean of sqrt(d^2 + eps^2) - eps over the
        pixels (and grad_weight times that of the finite differences);
        fitted to one pixel whose target is 1 in four draws out of five and
        0.5 in the fifth, a constant prediction settles at the median (1)
        under l1 and at the mean (0.9) under the MSE; --look-l1 needs the
        look loss."""
        p = torch.tensor([[[[0.2, 0.5], [0.9, 1.0]]]])
        q = torch.tensor([[[[0.0, 0.5], [1.0, 1.0]]]])
        eps = 1e-3
        d = torch.sqrt((p - q) ** 2 + eps * eps) - eps
        self.assertAlmostEqual(float(train.l1_and_gradients(p, q, 0)), float(d.mean()), places=6)
        dx = (p[..., :, 1:] - p[..., :, :-1]) - (q[..., :, 1:] - q[..., :, :-1])
        dy = (p[..., 1:, :] - p[..., :-1, :]) - (q[..., 1:, :] - q[..., :-1, :])
        ddx = (torch.sqrt(dx ** 2 + eps * eps) - eps).mean()
        ddy = (torch.sqrt(dy ** 2 + eps * eps) - eps).mean()
        self.assertAlmostEqual(float(train.l1_and_gradients(p, q, 2.0)),
                               float(d.mean() + 2.0 * (ddx + ddy)), places=6)
        targets = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.5]).view(5, 1, 1, 1)
        fits = {}
        for name, term in (("l1", train.l1_and_gradients), ("mse", train.mse_and_gradients)):
            a = torch.tensor(0.7, requires_grad=True)
            opt = torch.optim.SGD([a], lr=0.05)
            for _ in range(3000):
                opt.zero_grad()
                term(a.expand(5, 1, 1, 1), targets, 0).backward()
                opt.step()
            fits[name] = float(a)
        self.assertAlmostEqual(fits["mse"], 0.9, places=3)
        self.assertGreater(fits["l1"], 0.99)
        looks = train.eval_looks(1, "cpu")
        t = torch.tensor([0.3, 0.0, 1.0]).view(1, 3, 1, 1)
        pr = t + torch.tensor([0.1, 0.0, 0.0]).view(1, 3, 1, 1)
        cp, ct = train.composite(pr, *looks), train.composite(t, *looks)
        self.assertAlmostEqual(float(train.look_loss(pr, t, looks, 0, 0, l1=True)),
                               float(train.l1_and_gradients(cp, ct, 0)), places=7)
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", "--look-l1"])

    def assert_look_term(self, g, side, kwargs, weight, term, flag):
        """look_loss with kwargs (one term at weight) is look_loss without it
        plus weight times term(composite of the prediction, of the truth,
        the truth) on random frames of side x side; flag needs --loss look."""
        t = torch.rand(2, 3, side, side, generator=g)
        pr = torch.clamp(t + 0.2 * torch.rand(2, 3, side, side, generator=g), 0, 1)
        looks = train.eval_looks(2, "cpu")
        self.assertAlmostEqual(
            float(train.look_loss(pr, t, looks, 1.0, 0.1, **kwargs)),
            float(train.look_loss(pr, t, looks, 1.0, 0.1))
            + weight * float(term(train.composite(pr, *looks), train.composite(t, *looks), t)),
            places=6)
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", flag, "1"])

    def test_ssim_term_is_the_evaluations_ssim(self):
        """ssim_map is the evaluation's SSIM (Gaussian window of radius 5,
        sigma 1.5, C1 = 0.01^2, C2 = 0.03^2) at pixels whose window lies
        inside, computed here pixel by pixel; hair_ssim_loss averages 1 - it
        over the target's hair pixels only."""
        g = torch.Generator().manual_seed(11)
        p, q = torch.rand(1, 3, 16, 14, generator=g), torch.rand(1, 3, 16, 14, generator=g)
        q = 0.5 * p + 0.5 * q
        got = train.ssim_map(p, q)
        self.assertEqual(tuple(got.shape), (1, 6, 4))
        k = np.exp(-np.arange(-5, 6) ** 2 / (2 * 1.5 ** 2))
        w2 = np.outer(k, k) / np.outer(k, k).sum()
        P, Q = p[0].double().numpy(), q[0].double().numpy()
        for y, x in ((0, 0), (3, 2), (5, 3)):
            vals = []
            for c in range(3):
                a, b = P[c, y:y + 11, x:x + 11], Q[c, y:y + 11, x:x + 11]
                ma, mb = (w2 * a).sum(), (w2 * b).sum()
                va, vb = (w2 * a * a).sum() - ma * ma, (w2 * b * b).sum() - mb * mb
                cov = (w2 * a * b).sum() - ma * mb
                vals.append((2 * ma * mb + 1e-4) * (2 * cov + 9e-4)
                            / ((ma * ma + mb * mb + 1e-4) * (va + vb + 9e-4)))
            self.assertAlmostEqual(float(got[0, y, x]), float(np.mean(vals)), places=5)
        alpha = torch.zeros(1, 1, 16, 14)
        self.assertEqual(float(train.hair_ssim_loss(p, q, alpha)), 0.0)   # no hair
        self.assertAlmostEqual(float(train.hair_ssim_loss(p, p, alpha + 1)), 0.0, places=6)
        alpha[0, 0, 5 + 3, 5 + 2] = 0.4                                   # one hair pixel
        self.assertAlmostEqual(float(train.hair_ssim_loss(p, q, alpha)),
                               1 - float(got[0, 3, 2]), places=6)
        self.assert_look_term(g, 16, dict(ssim_weight=0.5), 0.5,
                              lambda cp, ct, t: train.hair_ssim_loss(cp, ct, t[:, 2:3]),
                              "--ssim-weight")

    def test_lattice_term_measures_the_periodic_error(self):
        """lattice_loss is the mean square of the error's part that repeats
        every `period` pixels: all of a tiled pattern's energy (less its
        mean), nothing of a uniform offset, nothing of an error that
        alternates from one period to the next, and for a frame of two
        windows, the mean of the two."""
        g = torch.Generator().manual_seed(5)
        period, n = 8, train.LATTICE_WINDOW
        q = torch.rand(1, 3, period * n, period * n, generator=g)
        tile = torch.rand(1, 3, period, period, generator=g) - 0.5
        lattice = tile.repeat(1, 1, n, n)
        want = float(((tile - tile.mean(dim=(2, 3), keepdim=True)) ** 2).mean())
        self.assertAlmostEqual(float(train.lattice_loss(q + lattice, q, period)), want, places=6)
        self.assertAlmostEqual(float(train.lattice_loss(q + 0.3, q, period)), 0.0, places=6)
        sign = torch.ones(n, n)
        sign[1::2] = -1                                # period 2 * period in y
        alternating = tile.repeat(1, 1, n, n) * sign.repeat_interleave(period, 0) \
            .repeat_interleave(period, 1)
        self.assertAlmostEqual(float(train.lattice_loss(q + alternating, q, period)), 0.0,
                               places=6)
        # Two windows side by side, the lattice in one only; a smaller image
        # uses the periods it has; one smaller than a period has none.
        wide = torch.cat([q + lattice, q], 3)
        self.assertAlmostEqual(float(train.lattice_loss(wide, torch.cat([q, q], 3), period)),
                               want / 2, places=6)
        small = (q + lattice)[:, :, :4 * period, :4 * period]
        self.assertAlmostEqual(float(train.lattice_loss(small, q[:, :, :4 * period, :4 * period],
                                                        period)), want, places=6)
        self.assertEqual(float(train.lattice_loss(q[:, :, :4, :4], q[:, :, :4, :4] + 1, period)),
                         0.0)
        self.assert_look_term(g, 32, dict(lattice=(3.0, 8)), 3.0,
                              lambda cp, ct, t: train.lattice_loss(cp, ct, 8), "--lattice-weight")

    def test_lowpass_term_measures_the_bias(self):
        """lowpass_loss is the mean square of the error's size x size block
        means: all of a uniform offset, nothing of an error whose blocks
        sum to zero (a checkerboard of pixels), the mean of the blocks'
        squares for an offset in some blocks only; 0 for an image smaller
        than a block."""
        g = torch.Generator().manual_seed(6)
        q = torch.rand(1, 3, 32, 32, generator=g)
        self.assertAlmostEqual(float(train.lowpass_loss(q + 0.3, q, 8)), 0.09, places=6)
        checker = (torch.arange(32)[:, None] + torch.arange(32)[None, :]) % 2 * 2 - 1.0
        self.assertAlmostEqual(float(train.lowpass_loss(q + 0.5 * checker, q, 8)), 0.0,
                               places=6)
        part = q.clone()
        part[:, :, :8, :8] += 0.4                      # one block of 16
        self.assertAlmostEqual(float(train.lowpass_loss(part, q, 8)), 0.16 / 16, places=6)
        self.assertEqual(float(train.lowpass_loss(q[:, :, :4, :4], q[:, :, :4, :4] + 1, 8)), 0.0)
        self.assert_look_term(g, 32, dict(lowpass=(4.0, 8)), 4.0,
                              lambda cp, ct, t: train.lowpass_loss(cp, ct, 8), "--lowpass-weight")
        # --lowpass-size a whole pixel or more.
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", "--loss", "look", "--lowpass-weight", "1",
                              "--lowpass-size", "0"])

    def test_below_input_term_is_a_hinge_on_the_own_input(self):
        """st_estimate is hf_st_estimate of each pixel's samples; the below
        term is 0 where the network equals its input or beats it, and where
        it is worse, its PSNR deficit in dB / 10 plus its SSIM deficit, with
        a gradient; crops without hair count 0 in the mean."""
        g = torch.Generator().manual_seed(9)
        spp, h, w = 4, 24, 24
        x = torch.rand(2, spp * 6, h, w, generator=g)
        x[:, 2::6] = torch.where(x[:, 2::6] > 0.5, x[:, 2::6], torch.zeros_like(x[:, 2::6]))
        est = train.st_estimate(x, spp)
        px = x[0, :, 3, 7].view(spp, 6)
        cov = px[:, 2] > 0
        n = int(cov.sum())
        self.assertAlmostEqual(float(est[0, 2, 3, 7]), n / spp, places=6)
        if n:
            self.assertAlmostEqual(float(est[0, 0, 3, 7]), float(px[cov, 0].mean()), places=5)
            self.assertAlmostEqual(float(est[0, 1, 3, 7]), float(px[cov, 1].mean()), places=5)
        t = torch.rand(2, 3, h, w, generator=g)
        t[:, 2] = t[:, 2].clamp(min=0.05)
        looks = train.eval_looks(2, "cpu")
        ct, ci = train.composite(t, *looks), train.composite(est, *looks)
        alpha = t[:, 2:3]
        self.assertEqual(float(train.below_input_loss(ci, ct, ci, alpha)), 0.0)
        self.assertEqual(float(train.below_input_loss(ct, ct, ci, alpha)), 0.0)
        # Worse than the input: the deficit in dB / 10 and in SSIM.
        worse = (ci + 0.3 * (ci - ct)).requires_grad_()
        got = train.below_input_loss(worse, ct, ci, alpha)
        eps = train.BELOW_INPUT_EPS
        want = 0.0
        for i in range(2):     # per crop, then the mean
            e = lambda a: float(((a[i] - ct[i]) ** 2).mean())
            s = lambda a: float(train.ssim_map(a[i:i + 1], ct[i:i + 1]).mean())
            want += (max(0.0, np.log10((e(worse) + eps) / (e(ci) + eps)))
                     + max(0.0, s(ci) - s(worse))) / 2
        self.assertAlmostEqual(float(got), want, places=5)
        self.assertGreater(float(got), 0.0)
        got.backward()
        self.assertGreater(float(worse.grad.abs().sum()), 0.0)
        # A crop without hair counts 0 in the mean.
        bald = alpha.clone()
        bald[1] = 0
        self.assertAlmostEqual(float(train.below_input_loss(worse.detach(), ct, ci, bald)),
                               float(train.below_input_loss(worse.detach()[:1], ct[:1], ci[:1],
                                                            alpha[:1])) / 2, places=5)
        # In the look loss, with its weight; the option needs --loss look.
        self.assertAlmostEqual(
            float(train.look_loss(est, t, looks, 1.0, 0.1, below=(2.0, x, spp))),
            float(train.look_loss(est, t, looks, 1.0, 0.1)), places=6)
        self.assertAlmostEqual(
            float(train.look_loss(worse.detach() * 0 + t * 0.5, t, looks, 1.0, 0.1,
                                  below=(2.0, x, spp))),
            float(train.look_loss(t * 0.5, t, looks, 1.0, 0.1))
            + 2.0 * float(train.below_input_loss(train.composite(t * 0.5, *looks), ct, ci,
                                                 alpha)), places=5)
        with self.assertRaises(SystemExit):
            train.parse_args(["--out", "x", "--below-input-weight", "1"])

    # -- training --------------------------------------------------------------

    def assert_c_infer_is_pytorch(self, weights, frame, x):
        """hairfilter infer (cpu-ref) of weights on the dataset EXR frame gives
        what PyTorch gives on its network input x ([h][w][channels])."""
        out = os.path.join(self.work, "result.exr")
        subprocess.run([ARGS.hairfilter, "infer", "--backend", "cpu-ref", "--weights", weights,
                        "--in", frame, "--out", out], check=True, capture_output=True)
        names, res = dataset.read_exr(out)
        c_out = dataset.pick_channels(names, res, dataset.TARGETS)
        net = hfnet.load_model(weights).eval()
        with torch.no_grad():
            ref = net(torch.from_numpy(x.transpose(2, 0, 1).copy())[None])[0].numpy()
        ref = ref.transpose(1, 2, 0)
        rel = np.linalg.norm(c_out - ref) / np.linalg.norm(ref)
        self.assertLess(rel, 1e-4, f"C vs PyTorch relative L2 {rel:.3g}")

    def test_loss_falls_and_export_roundtrips(self):
        run = os.path.join(self.work, "run")
        exp = os.path.join(self.work, "base.safetensors")
        r = run_train("--data", self.data, "--variant", "Base", "--out", run, "--steps", "40",
                      "--batch", "4", "--crop", "48", "--lr", "2e-3", "--val-every", "5",
                      "--export", exp)
        self.assertIn("40/40", r.stderr)              # the progress line
        self.assertIn("ETA", r.stderr)
        log = read_log(run)
        self.assertEqual([x["step"] for x in log], list(range(5, 41, 5)))
        first, last = log[0], log[-1]
        self.assertLess(last["loss"], 0.6 * first["loss"], log)
        self.assertLess(last["val"], first["val"], log)

        # C loader + writer: every tensor comes back bit-exactly.
        back = os.path.join(self.work, "back.safetensors")
        subprocess.run([ARGS.roundtrip, exp, back], check=True, capture_output=True)
        cfg_a, sd_a = hfnet.load_safetensors(exp)
        cfg_b, sd_b = hfnet.load_safetensors(back)
        self.assertEqual(cfg_a["levels"], cfg_b["levels"])
        self.assertEqual(cfg_a["spp"], cfg_b["spp"])
        self.assertEqual(sorted(sd_a), sorted(sd_b))
        for k in sd_a:
            self.assertTrue(torch.equal(sd_a[k], sd_b[k]), k)

        # C inference (cpu-ref) on a dataset EXR against PyTorch.
        frame = dataset.read_manifest(self.data)[0]["file"]
        feat, _ = dataset.load_frame(frame, spp=4, dtype=np.float32)
        self.assert_c_infer_is_pytorch(exp, frame, feat.reshape(SIZE, SIZE, 24))

        # F16 export: what C reads is exactly the halves' values.
        exp16 = os.path.join(self.work, "base16.safetensors")
        run_train("--out", run, "--resume", "--steps", "40", "--export", exp16,
                  "--export-dtype", "F16")
        back16 = os.path.join(self.work, "back16.safetensors")
        subprocess.run([ARGS.roundtrip, exp16, back16], check=True, capture_output=True)
        _, sd16 = hfnet.load_safetensors(exp16)
        _, sdb16 = hfnet.load_safetensors(back16)
        for k in sd16:
            self.assertTrue(torch.equal(sd16[k], sdb16[k]), k)
            self.assertTrue(torch.equal(sd16[k], sd_a[k].half().float()), k)

    def test_refusals_say_what_to_give(self):
        """A crop larger than the frames, styles the data does not hold and a
        directory without frames are refused before training, naming what
        would work, without a traceback."""
        cmd = [sys.executable, os.path.join(WEIGHTS, "train.py"), "--threads", "1", "--device",
               "cpu", "--data", self.data, "--variant", "Base", "--steps", "1",
               "--out", os.path.join(self.work, "run_refused")]
        p = subprocess.run(cmd + ["--crop", str(2 * SIZE)], capture_output=True, text=True)
        self.assertNotEqual(p.returncode, 0)
        self.assertIn(f"--crop {2 * SIZE} is larger than the smallest frame", p.stderr)
        self.assertIn(f"({SIZE}x{SIZE})", p.stderr)
        self.assertIn(f"use --crop {SIZE} or less", p.stderr)
        p = subprocess.run(cmd + ["--styles", "curly"], capture_output=True, text=True)
        self.assertNotEqual(p.returncode, 0)
        self.assertIn("it has straight, wavy", p.stderr)
        self.assertIn("--styles ''", p.stderr)
        missing = os.path.join(self.work, "no_such_set")
        p = subprocess.run(cmd + ["--data", missing], capture_output=True, text=True)
        self.assertNotEqual(p.returncode, 0)
        self.assertIn(f"train.py: {missing}: no such directory", p.stderr)
        self.assertNotIn("Traceback", p.stderr)

    def test_no_validation_frames_said_so(self):
        """Without validation frames (--val-fraction 0, or a style of one
        frame) the last line says so rather than 'validation nan'."""
        r = run_train("--data", self.data, "--variant", "Small", "--steps", "1", "--batch", "1",
                      "--crop", "32", "--val-fraction", "0",
                      "--out", os.path.join(self.work, "run_no_val"))
        self.assertIn("0 validation frames", r.stderr)
        self.assertIn("validation none (no validation frames)", r.stderr)
        self.assertNotIn("validation nan", r.stderr)

    def test_init_range_joins_the_exported_range(self):
        """Weights trained from others (--init) record the union of the
        others' input range and their own frames'; without --init, their
        frames' alone."""
        import input_stats
        import stamp_range
        a = os.path.join(self.work, "range_a.safetensors")
        run_train("--data", self.data, "--variant", "Small", "--out", os.path.join(self.work, "ra"),
                  "--steps", "1", "--batch", "2", "--crop", "48", "--export", a)
        own = json.loads(hfnet.load_metadata(a)["input_range"])
        wide = dict(own, frames=1000, strand_alpha_p50=[1e-4, 0.999])
        b = os.path.join(self.work, "range_b.safetensors")
        stamp_range.stamp(a, wide, b)
        c = os.path.join(self.work, "range_c.safetensors")
        run_train("--data", self.data, "--variant", "Small", "--init", b,
                  "--out", os.path.join(self.work, "rc"), "--steps", "1", "--batch", "2",
                  "--crop", "48", "--export", c)
        got = json.loads(hfnet.load_metadata(c)["input_range"])
        self.assertEqual(got, input_stats.union_range(own, wide))
        self.assertEqual(got["frames"], own["frames"] + 1000)
        self.assertEqual(got["strand_alpha_p50"], [1e-4, 0.999])
        self.assertEqual(got["hair_fraction"], own["hair_fraction"])

    def test_kernel_ac_trains_and_the_c_backend_agrees(self):
        """KernelAC trains from the synthetic frames' acst4.* (the estimate
        after the samples in every input), exports with its 'estimate', and
        hairfilter infer (cpu-ref) reads the frame's estimate and gives
        PyTorch's result; a frame without acst4.* is refused naming the
        render option."""
        run = os.path.join(self.work, "run_ac")
        exp = os.path.join(self.work, "kernel_ac.safetensors")
        r = run_train("--data", self.data, "--variant", "KernelAC", "--out", run, "--steps", "6",
                      "--batch", "2", "--crop", "48", "--val-every", "3", "--export", exp)
        self.assertIn("6/6", r.stderr)
        cfg = hfnet.load_safetensors(exp)[0]
        self.assertEqual((cfg["estimate"], cfg["in_channels"]), ("alpha_corrected", 27))
        frame = dataset.read_manifest(self.data)[0]["file"]
        feat, _ = dataset.load_frame(frame, spp=4, dtype=np.float32)
        est = dataset.load_estimate(frame, np.float32)
        self.assert_c_infer_is_pytorch(exp, frame,
                                       np.concatenate([feat.reshape(SIZE, SIZE, 24), est], -1))
        out = os.path.join(self.work, "result_ac.exr")
        bare = os.path.join(self.work, "no_estimate.exr")
        names, data = dataset.read_exr(frame)
        keep = [n for n in names if not n.startswith("acst4.")]
        dataset.write_exr(bare, keep, dataset.pick_channels(names, data, keep))
        p = subprocess.run([ARGS.hairfilter, "infer", "--backend", "cpu-ref", "--weights", exp,
                            "--in", bare, "--out", out], capture_output=True, text=True)
        self.assertNotEqual(p.returncode, 0)
        self.assertIn("acst4.color", p.stderr)
        self.assertIn("--no-alpha-corrected", p.stderr)

    def test_target_input_trains_towards_the_own_input(self):
        """--target input: the target is st_estimate of the crop's own
        samples; a short run falls towards it, records it, and ends closer
        to its input than to the truth."""
        g = torch.Generator().manual_seed(4)
        x, y = torch.rand(2, 24, 8, 8, generator=g), torch.rand(2, 3, 8, 8, generator=g)
        self.assertTrue(torch.equal(train.training_target(x, y, "input", 4),
                                    train.st_estimate(x, 4)))
        self.assertIs(train.training_target(x, y, "truth", 4), y)
        run = os.path.join(self.work, "target_input")
        exp = run + ".safetensors"
        run_train("--data", self.data, "--variant", "Small", "--out", run, "--steps", "40",
                  "--batch", "4", "--crop", "48", "--lr", "3e-3", "--val-every", "10",
                  "--target", "input", "--export", exp)
        log = read_log(run)
        self.assertLess(log[-1]["val"], 0.85 * log[0]["val"], log)
        with open(os.path.join(run, "summary.json")) as f:
            self.assertEqual(json.load(f)["target"], "input")
        feat, tgt = dataset.load_frame(dataset.read_manifest(self.data)[0]["file"], spp=4,
                                       dtype=np.float32)
        xf = torch.from_numpy(feat.reshape(SIZE, SIZE, 24).transpose(2, 0, 1).copy())[None]
        with torch.no_grad():
            out = hfnet.load_model(exp).eval()(xf)
        gt = torch.from_numpy(tgt.transpose(2, 0, 1).copy())[None]
        to_input = float(((out - train.st_estimate(xf, 4)) ** 2).mean())
        self.assertLess(to_input, float(((out - gt) ** 2).mean()))

    def test_clip_grad_norm_is_recorded_and_applied(self):
        """--clip-grad-norm: the log records each interval's median norm
        before clipping and the share of steps clipped; a clip far under
        the norms clips every step and changes the run; without it no
        share is recorded; a negative or infinite clip is refused."""
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "4", "--steps", "8", "--seed", "3"]
        runs = {}
        for name, extra in (("free", []), ("tight", ["--clip-grad-norm", "1e-6"])):
            out = os.path.join(self.work, "clip_" + name)
            run_train(*common, "--out", out, "--export", out + ".safetensors", *extra)
            runs[name] = (read_log(out), hfnet.load_safetensors(out + ".safetensors")[1])
            with open(os.path.join(out, "summary.json")) as f:
                self.assertEqual(json.load(f)["clip_grad_norm"], float(extra[1]) if extra else 0)
        free, tight = runs["free"][0], runs["tight"][0]
        for rec in free + tight:
            self.assertGreater(rec["grad_norm"], 1e-6, rec)
        self.assertTrue(all("clipped" not in r for r in free), free)
        self.assertEqual([r["clipped"] for r in tight], [1.0, 1.0], tight)
        self.assertTrue(any(not torch.equal(runs["free"][1][k], runs["tight"][1][k])
                            for k in runs["free"][1]))
        for bad in ("-1", "inf"):
            with self.assertRaises(SystemExit):
                train.parse_args(["--out", "x", "--clip-grad-norm", bad])

    def test_weight_ema_exports_the_moving_average_and_resumes(self):
        """--weight-ema D: after two steps the export is D * (the weights
        after step 1) + (1 - D) * (after step 2), the average starting at
        the first step's weights; a run stopped after step 1 and resumed
        exports the same; a decay outside [0, 1) is refused."""
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "1", "--ckpt-every", "1", "--seed", "9", "--steps", "2",
                  "--lr", "1e-2"]
        w = os.path.join(self.work, "ema_")
        run_train(*common, "--out", w + "r1", "--stop-at", "1", "--export", w + "1.safetensors")
        run_train(*common, "--out", w + "r2", "--export", w + "2.safetensors")
        run_train(*common, "--out", w + "re", "--weight-ema", "0.25",
                  "--export", w + "e.safetensors")
        run_train(*common, "--out", w + "rs", "--weight-ema", "0.25", "--stop-at", "1")
        run_train("--out", w + "rs", "--resume", "--steps", "2", "--export", w + "s.safetensors")
        _, s1 = hfnet.load_safetensors(w + "1.safetensors")
        _, s2 = hfnet.load_safetensors(w + "2.safetensors")
        _, se = hfnet.load_safetensors(w + "e.safetensors")
        _, ss = hfnet.load_safetensors(w + "s.safetensors")
        moved = 0
        for k in s1:
            want = 0.25 * s1[k] + 0.75 * s2[k]
            self.assertTrue(torch.allclose(se[k], want, rtol=0, atol=1e-7), f"{k}: not the average")
            self.assertTrue(torch.equal(ss[k], se[k]), f"{k} differs after resume")
            moved += int(not torch.equal(se[k], s2[k]))
        self.assertGreater(moved, 0, "the average is the last step's weights")
        for bad in ("1", "-0.1"):
            cmd = [sys.executable, os.path.join(WEIGHTS, "train.py"), "--out", w + "bad",
                   "--weight-ema", bad]
            r = subprocess.run(cmd, capture_output=True, text=True)
            self.assertEqual(r.returncode, 2)
            self.assertIn("--weight-ema must be a decay in [0, 1)", r.stderr)

    def test_resume_refuses_other_options_and_a_new_run_refuses_the_out(self):
        """--resume takes the run's options from its checkpoint: a command
        line that gives one of them another value is refused naming each
        (the run's value, this one's) and what may change, and the
        checkpoint is left; the same values (a path spelt otherwise) and a
        larger --steps, other threads and cadence are taken. A new run into
        an --out that holds a checkpoint is refused, its log left. Records
        logged after the checkpoint are not repeated by the resumed run."""
        run = os.path.join(self.work, "resume_opts")
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "1", "--ckpt-every", "1", "--seed", "9", "--loss", "look",
                  "--lr", "1e-3"]
        run_train(*common, "--steps", "3", "--stop-at", "1", "--out", run)
        ckpt = os.path.join(run, "checkpoint.pt")
        with open(ckpt, "rb") as f:
            before = f.read()
        log_before = read_log(run)
        self.assertEqual([r["step"] for r in log_before], [1])
        cmd = [sys.executable, os.path.join(WEIGHTS, "train.py"), "--threads", "1",
               "--device", "cpu", "--out", run]
        other = os.path.join(self.work, "other_data")
        p = subprocess.run(cmd + ["--resume", "--data", other, "--variant", "Kernel", "--loss",
                                  "paper", "--lr", "5e-3", "--crop", "48", "--steps", "3"],
                           capture_output=True, text=True)
        self.assertEqual(p.returncode, 1, p.stderr)
        for want in (f"--data is {self.data} there, {other} here",
                     "--variant is Small there, Kernel here", "--loss is look there, paper here",
                     "--lr is 0.001 there, 0.005 here", "--crop is 32 there, 48 here",
                     f"--resume: {ckpt} is a run with other options",
                     "may change only --steps", "--out another directory"):
            self.assertIn(want, p.stderr)
        self.assertNotIn("--batch", p.stderr)
        self.assertNotIn("Traceback", p.stderr)
        p = subprocess.run(cmd + ["--resume", "--exact-clamps"], capture_output=True, text=True)
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn("--exact-clamps is off there, on here", p.stderr)
        # A new run into the same --out.
        p = subprocess.run(cmd + common + ["--steps", "3"], capture_output=True, text=True)
        self.assertEqual(p.returncode, 1, p.stderr)
        self.assertIn(f"--out {run} holds a run ({ckpt}): add --resume", p.stderr)
        self.assertIn(f"another --out (or remove {run})", p.stderr)
        with open(ckpt, "rb") as f:
            self.assertEqual(f.read(), before, "a refused command changed the checkpoint")
        self.assertEqual(read_log(run), log_before)
        # A record logged after the checkpoint (a run killed between the two).
        with open(os.path.join(run, "log.jsonl"), "a") as f:
            f.write(json.dumps(dict(log_before[0], step=2)) + "\n")
        # The same options, the data spelt with a trailing slash; a longer run.
        r = run_train(*common, "--data", self.data + os.sep, "--variant", "small", "--out", run,
                      "--resume", "--steps", "4", "--val-every", "2", "--ckpt-every", "3")
        self.assertIn("resumed Small at step 1", r.stderr)
        self.assertEqual([x["step"] for x in read_log(run)], [1, 2, 4])
        with open(os.path.join(run, "summary.json")) as f:
            summary = json.load(f)
        self.assertEqual((summary["steps"], summary["lr"], summary["loss"]), (4, 1e-3, "look"))

    def test_resume_with_only_out_finishes_the_run_as_started(self):
        """`--out RUN --resume` (docs/TRAINING.md: the options left out come
        from the checkpoint) runs to the run's own --steps on its cadence and
        exports where it said; it is the uninterrupted run to the bit. A
        --stop-at of the first command is not kept (it would stop again at
        once)."""
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "2", "--ckpt-every", "2", "--seed", "9", "--loss", "paper",
                  "--steps", "4"]
        a, b = os.path.join(self.work, "only_out_a"), os.path.join(self.work, "only_out_b")
        run_train(*common, "--out", a, "--export", a + ".safetensors")
        r = run_train(*common, "--out", b, "--stop-at", "2", "--export", b + ".safetensors")
        # The stopped run's export says it is not the finished run's.
        self.assertIn("the weights of step 2 of 4; --resume finishes the run", r.stderr)
        os.remove(b + ".safetensors")
        r = run_train("--out", b, "--resume")
        self.assertIn("resumed Small at step 2", r.stderr)
        self.assertIn("step 4,", r.stderr)
        self.assertEqual([x["step"] for x in read_log(b)], [2, 4])
        self.assertTrue(os.path.exists(b + ".safetensors"), "the run's --export was not written")
        self.assertNotIn("the weights of step", r.stderr)
        _, sa = hfnet.load_safetensors(a + ".safetensors")
        _, sb = hfnet.load_safetensors(b + ".safetensors")
        for k in sa:
            self.assertTrue(torch.equal(sa[k], sb[k]), f"{k} differs after resume")

    def test_resume_export_elsewhere_is_that_commands_own(self):
        """A resume that exports elsewhere (--export, --export-dtype) trains
        on and checkpoints, but the run keeps its own export: the next
        `--out RUN --resume` writes the run's file, not the other one (it
        wrote the other, say a file a daemon serves, from then on)."""
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "2", "--ckpt-every", "2", "--seed", "9", "--loss", "paper",
                  "--steps", "6"]
        run = os.path.join(self.work, "export_own")
        mine, other = run + ".safetensors", run + "_other.safetensors"
        run_train(*common, "--out", run, "--stop-at", "2", "--export", mine)
        os.remove(mine)
        r = run_train("--out", run, "--resume", "--stop-at", "4", "--export", other,
                      "--export-dtype", "F16")
        # Where the run's own export goes is said beside this one.
        self.assertIn(f"--resume finishes the run and exports again (to the run's --export, "
                      f"{os.path.abspath(mine)})", r.stderr)
        self.assertTrue(os.path.exists(other), "this command's --export was not written")
        self.assertFalse(os.path.exists(mine), "the run's export was written by a command "
                         "that exports elsewhere")
        os.remove(other)
        r = run_train("--out", run, "--resume")
        self.assertIn("step 6,", r.stderr)
        self.assertTrue(os.path.exists(mine), "the run's own --export was not written")
        self.assertFalse(os.path.exists(other), "the other command's --export stuck to the run")
        meta, sd = hfnet.load_safetensors(mine)
        self.assertTrue(all(v.dtype == torch.float32 for v in sd.values()),
                        "the other command's --export-dtype F16 stuck to the run")

    def test_resume_from_another_directory(self):
        """A run started with relative --data and --export and taken up with
        `--out RUN --resume` from another directory reads the same frames
        and exports to the same file (the checkpoint keeps the paths
        absolute; they were taken from the resumed command's directory)."""
        run = os.path.join(self.work, "cwd_run")
        exp = os.path.join(self.work, "cwd_run.safetensors")
        cmd = [sys.executable, os.path.join(WEIGHTS, "train.py"), "--threads", "1",
               "--device", "cpu"]
        r = subprocess.run(cmd + ["--data", os.path.basename(self.data), "--variant", "Small",
                                  "--batch", "2", "--crop", "32", "--steps", "2", "--stop-at", "1",
                                  "--out", run, "--export", os.path.basename(exp)],
                           cwd=self.work, capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        os.remove(exp)
        elsewhere = os.path.join(self.work, "elsewhere")
        os.makedirs(elsewhere, exist_ok=True)
        r = subprocess.run(cmd + ["--out", run, "--resume"], cwd=elsewhere, capture_output=True,
                           text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn("step 2,", r.stderr)
        self.assertTrue(os.path.exists(exp), "not exported where the run said")
        self.assertEqual(os.listdir(elsewhere), [])

    def test_resume_exports_without_the_init_file(self):
        """A fine-tune's export joins its --init weights' input range; a
        run resumed after that file was moved or deleted still exports it
        (kept in the checkpoint), where it was a traceback after the run."""
        init = os.path.join(self.work, "init_gone.safetensors")
        shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), init)
        run = os.path.join(self.work, "init_gone")
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "1", "--ckpt-every", "1", "--steps", "2", "--init", init]
        run_train(*common, "--stop-at", "1", "--out", run, "--export", run + "_1.safetensors")
        os.remove(init)
        r = run_train("--out", run, "--resume", "--export", run + "_2.safetensors")
        self.assertIn("step 2,", r.stderr)
        first = json.loads(hfnet.load_metadata(run + "_1.safetensors")["input_range"])
        second = json.loads(hfnet.load_metadata(run + "_2.safetensors")["input_range"])
        self.assertEqual(first, second)
        own = json.loads(hfnet.load_metadata(os.path.join(WEIGHTS, "small.safetensors"))
                         ["input_range"])
        self.assertGreater(second["frames"], own["frames"], "the init's range was not joined")

    def test_resume_equals_uninterrupted(self):
        self.resume_equals_uninterrupted("paper")

    def test_resume_equals_uninterrupted_look_loss(self):
        self.resume_equals_uninterrupted("look")

    def resume_equals_uninterrupted(self, loss):
        common = ["--data", self.data, "--variant", "Small", "--batch", "2", "--crop", "32",
                  "--val-every", "4", "--ckpt-every", "4", "--seed", "9", "--loss", loss]
        a, b = os.path.join(self.work, "ra_" + loss), os.path.join(self.work, "rb_" + loss)
        run_train(*common, "--out", a, "--steps", "12", "--export", a + ".safetensors")
        run_train(*common, "--out", b, "--steps", "12", "--stop-at", "8")
        r = run_train("--out", b, "--resume", "--steps", "12", "--export", b + ".safetensors")
        self.assertIn("resumed Small at step 8", r.stderr)
        _, sa = hfnet.load_safetensors(a + ".safetensors")
        _, sb = hfnet.load_safetensors(b + ".safetensors")
        for k in sa:
            self.assertTrue(torch.equal(sa[k], sb[k]), f"{k} differs after resume")
        self.assertEqual(read_log(a), [dict(x, time=y["time"]) for x, y in
                                       zip(read_log(b), read_log(a))])


class EvalTable(unittest.TestCase):
    """weights/eval_table.py on a small eval document."""

    def setUp(self):
        bucket = dict(frames=1, psnr=30.0, ssim=0.9)
        method = lambda label, kind: dict(  # noqa: E731
            method=label, kind=kind, overall=bucket,
            **{k: [bucket] for k in ("strand_width_frames", "coverage_frames",
                                      "resolution_frames")})
        doc = dict(format="hairfilter-eval", frames=1,
                   groupings=[dict(key=k, buckets=[dict(bucket="b", frames=1)])
                              for k in ("strand_width_frames", "coverage_frames",
                                        "resolution_frames")],
                   methods=[method("stochastic transparency 4 spp", "baseline"),
                            method("ours Small (small.safetensors)", "network")])
        self.doc = os.path.join(ARGS.work, "eval_table.json")
        os.makedirs(ARGS.work, exist_ok=True)
        with open(self.doc, "w") as f:
            json.dump(doc, f)

    def table(self, methods):
        return subprocess.run([sys.executable, os.path.join(WEIGHTS, "eval_table.py"), self.doc,
                               "--methods", methods], capture_output=True, text=True)

    def test_methods_that_match_no_label_are_refused_naming_the_labels(self):
        r = self.table("4 spp,Small")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.count("\n| "), 2, r.stdout)
        for wanted, partial in (("Base", False), ("Small,Base,st 8", True)):
            r = self.table(wanted)
            self.assertNotEqual(r.returncode, 0, wanted)
            self.assertEqual(r.stdout, "", "a table without the rows asked for")
            self.assertIn("no method of", r.stderr)
            self.assertIn("'Base'", r.stderr)
            self.assertEqual("'st 8'" in r.stderr, partial)
            self.assertNotIn("'Small'", r.stderr)
            self.assertEqual("(the others matched)" in r.stderr, partial)
            self.assertIn("its labels: stochastic transparency 4 spp; "
                          "ours Small (small.safetensors)", r.stderr)


class ScriptRefusals(unittest.TestCase):
    """The scripts docs/TRAINING.md runs, given what does not exist or
    cannot be read, exit with one line naming it and what to do, never a
    traceback: an unknown --variant (before any data is read), a missing or
    cut-short --init, a checkpoint that cannot be read, a --data directory
    that does not exist or whose manifest is not JSON; stamp_range.py,
    regime_table.py and eval_table.py likewise."""

    @classmethod
    def setUpClass(cls):
        cls.work = os.path.join(ARGS.work, "refusals")
        shutil.rmtree(cls.work, ignore_errors=True)
        os.makedirs(cls.work)
        cls.missing = os.path.join(cls.work, "nothing_here")
        cls.bad_manifest = os.path.join(cls.work, "bad_manifest")
        os.makedirs(cls.bad_manifest)
        with open(os.path.join(cls.bad_manifest, "manifest.json"), "w") as f:
            f.write('{"frames": [')
        cls.cut = os.path.join(cls.work, "cut.safetensors")
        with open(os.path.join(WEIGHTS, "small.safetensors"), "rb") as f:
            data = f.read()
        with open(cls.cut, "wb") as f:
            f.write(data[:len(data) - 1000])

    def script(self, name, *argv):
        """Runs weights/NAME as __main__ with argv in this process (torch is
        imported once, not once a refusal): it must end in SystemExit with a
        non-zero status, any other exception being the traceback a user
        would have seen. Its stderr, and a SystemExit message, are returned."""
        path = os.path.join(WEIGHTS, name)
        err = io.StringIO()
        saved = sys.argv
        sys.argv = [path, *argv]
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                runpy.run_path(path, run_name="__main__")
        except SystemExit as e:
            code = e.code
        else:
            code = 0
        finally:
            sys.argv = saved
        text = err.getvalue()
        if isinstance(code, str):   # sys.exit("message") prints it to stderr
            text, code = text + code + "\n", 1
        self.assertNotEqual(code, 0, text)
        return text

    def test_train(self):
        out = os.path.join(self.work, "run")
        err = self.script("train.py", "--data", self.missing, "--variant", "Bogus", "--out", out)
        self.assertIn("--variant 'Bogus' is not a variant: give one of Base,", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Small", "--init",
                          os.path.join(self.work, "none.safetensors"), "--out", out)
        self.assertIn("train.py: --init: " + os.path.join(self.work, "none.safetensors")
                      + ": No such file or directory", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Small", "--init",
                          self.cut, "--out", out)
        self.assertIn(f"train.py: --init: {self.cut}: tensor '", err)
        self.assertIn("the file is cut short", err)
        # Weights of another variant: the difference named, where the levels
        # (all it named) are the same.
        err = self.script("train.py", "--data", self.missing, "--variant", "Kernel", "--init",
                          os.path.join(WEIGHTS, "kernel_ac.safetensors"), "--out", out)
        self.assertIn("is KernelAC, which cannot start --variant Kernel: it reads 4 samples and "
                      "the alpha-corrected estimate (27 input channels), Kernel 4 samples (24 "
                      "input channels)", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Residual", "--init",
                          os.path.join(WEIGHTS, "base.safetensors"), "--out", out)
        self.assertIn("architecture unet, not residual", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Shallow", "--init",
                          os.path.join(WEIGHTS, "base.safetensors"), "--out", out)
        self.assertIn("3 levels [32, 64, 128], not 2 [32, 64]", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Small", "--out", out)
        self.assertIn(f"train.py: {self.missing}: no such directory", err)
        err = self.script("train.py", "--data", self.bad_manifest, "--variant", "Small",
                          "--out", out)
        self.assertIn(f"{self.bad_manifest}/manifest.json: not JSON", err)
        # The parent of sets: the sets named, to give instead.
        parent = os.path.join(self.work, "sets")
        for name in ("b", "a"):
            synth_dataset.main(["--out", os.path.join(parent, name), "--styles", "straight",
                                "--count", "1", "--size", "16x16", "--st", "", "--seed", "3"])
        err = self.script("train.py", "--data", parent, "--variant", "Small", "--out", out)
        self.assertIn(f"{parent}: no frames of its own; it holds 2 set(s) (directories with a "
                      f"manifest.json): give them, comma-separated (--data {parent}/a,"
                      f"{parent}/b)", err)
        # A set given twice: its frames would be trained on twice, and the
        # validation frame's twin trained on (the split goes by file name).
        a = os.path.join(parent, "a")
        err = self.script("train.py", "--data", f"{a},{a}/", "--variant", "Small", "--out", out)
        self.assertIn(f"{a}/straight_0000.exr is given twice (by the sets {a} and {a}/: a set "
                      "given twice, or a manifest that lists the frame twice): give each set "
                      "once", err)
        err = self.script("stamp_range.py", os.path.join(WEIGHTS, "small.safetensors"),
                          "--data", f"{a},{a}", "--out", os.path.join(self.work, "s.safetensors"))
        self.assertIn("straight_0000.exr is given twice", err)
        # --resume of an --out that holds no run: said, and the directory
        # is not made.
        nowhere = os.path.join(self.work, "no_run_here")
        err = self.script("train.py", "--out", nowhere, "--resume")
        self.assertIn(f"train.py: --resume: {nowhere} holds no checkpoint.pt: name the --out of "
                      "the run to take up, or leave out --resume", err)
        self.assertFalse(os.path.exists(nowhere))
        # A new run refused for its data (a set given twice) leaves no empty
        # --out behind (it did); a process of its own, since the folder goes
        # at the interpreter's exit.
        fresh = os.path.join(self.work, "refused_run")
        p = subprocess.run([sys.executable, os.path.join(WEIGHTS, "train.py"), "--data",
                            f"{a},{a}", "--variant", "Small", "--out", fresh],
                           capture_output=True, text=True)
        self.assertNotEqual(p.returncode, 0)
        self.assertIn("is given twice", p.stderr)
        self.assertFalse(os.path.exists(fresh), "a refused run left its empty --out")
        # A checkpoint that cannot be read: the file named, and what to do.
        run = os.path.join(self.work, "torn")
        os.makedirs(run)
        with open(os.path.join(run, "checkpoint.pt"), "wb") as f:
            f.write(b"PK\3\4 not a checkpoint")
        err = self.script("train.py", "--out", run, "--resume")
        self.assertIn(f"train.py: --resume: {run}/checkpoint.pt cannot be read (", err)
        self.assertIn("restore it, or start the run again into another --out", err)
        # Frames of fewer samples than the variant reads: which --spp to render.
        one = os.path.join(self.work, "one_spp")
        synth_dataset.main(["--out", one, "--styles", "straight", "--count", "2",
                            "--size", "32x32", "--spp", "1", "--st", "", "--seed", "4"])
        err = self.script("train.py", "--data", one, "--variant", "Small", "--crop", "16",
                          "--out", out)
        self.assertIn("1 samples per pixel, the variant reads 4: render the set with --spp 4",
                      err)
        # Frames without the ground truth (rendered with --gt-ss 0).
        nogt = os.path.join(self.work, "no_truth")
        synth_dataset.main(["--out", nogt, "--styles", "straight", "--count", "2",
                            "--size", "32x32", "--st", "", "--seed", "4"])
        for e in dataset.read_manifest(nogt):
            names, data = dataset.read_exr(e["file"])
            keep = [i for i, n in enumerate(names) if not n.startswith("gt.")]
            dataset.write_exr(e["file"], [names[i] for i in keep], data[..., keep])
        err = self.script("train.py", "--data", nogt, "--variant", "Small", "--crop", "16",
                          "--out", out)
        self.assertIn("no ground truth (gt.color, gt.highlight, gt.alpha): render the set "
                      "without --gt-ss 0", err)

    def test_numbers_out_of_range(self):
        """Counts and rates out of range are refused by name before any
        frame is read: they did nothing (--steps 0) or ended in a traceback
        from numpy or torch. A crop the U-Net cannot halve is named with
        the multiple it needs."""
        out = os.path.join(self.work, "numbers")
        for flag, value, want in (("--steps", "0", "--steps 0: must be 1 or more"),
                                  ("--batch", "0", "--batch 0: must be 1 or more"),
                                  ("--val-every", "0", "--val-every 0: must be 1 or more"),
                                  ("--ckpt-every", "0", "--ckpt-every 0: must be 1 or more"),
                                  ("--threads", "0", "--threads 0: must be 1 or more"),
                                  ("--lr", "-1", "--lr -1.0: must be a finite rate above 0"),
                                  ("--lr", "nan", "--lr nan: must be a finite rate above 0"),
                                  ("--val-fraction", "1.5", "--val-fraction 1.5: must be a "
                                                            "share in [0, 1)")):
            err = self.script("train.py", "--data", self.missing, "--variant", "Small",
                              "--out", out, flag, value)
            self.assertIn(want, err)
            self.assertNotIn("no such directory", err, "refused after the data was looked at")
        # An export that cannot be written: said before training, not after.
        err = self.script("train.py", "--data", self.missing, "--variant", "Small", "--out", out,
                          "--export", self.work + os.sep)
        self.assertIn(f"--export {self.work}{os.sep} is a directory: give the weights file's "
                      "name", err)
        blocker = os.path.join(self.work, "a_file")
        with open(blocker, "w") as f:
            f.write("x")
        err = self.script("train.py", "--data", self.missing, "--variant", "Small", "--out", out,
                          "--export", os.path.join(blocker, "w.safetensors"))
        self.assertIn(f"cannot make {blocker}", err)
        # Kernels the C loader takes, and only on the kernel variants: a
        # radius of 5 trained weights no backend loads, and --kernel-radius
        # on Small was dropped in silence.
        err = self.script("train.py", "--data", self.missing, "--variant", "Kernel",
                          "--kernel-radius", "5", "--out", out)
        self.assertIn("--kernel-radius 5: must be 1..4", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Kernel",
                          "--kernel-hidden", "65", "--out", out)
        self.assertIn("--kernel-hidden 65: must be 0..64", err)
        err = self.script("train.py", "--data", self.missing, "--variant", "Small",
                          "--kernel-radius", "2", "--out", out)
        self.assertIn("--kernel-radius and --kernel-hidden are for the kernel variants "
                      "(Kernel, KernelAC), not Small", err)
        with open(os.path.join(HERE, "..", "..", "src", "hfcore.h")) as f:
            h = f.read()
        err = self.script("train.py", "--data", self.missing, "--variant", "Small",
                          "--levels", "8,8,8,8,8,8,8,8,8", "--out", out)
        self.assertIn("at most 8 levels of at most 4096 channels", err)
        for name, value in (("HF_MAX_LEVELS", train.MAX_LEVELS),
                            ("HF_MAX_CHANNELS", train.MAX_CHANNELS),
                            ("HF_KERNEL_MAX_RADIUS", train.KERNEL_MAX_RADIUS),
                            ("HF_KERNEL_MAX_HIDDEN", train.KERNEL_MAX_HIDDEN)):
            self.assertRegex(h, rf"#define {name} +{value}\b", f"train.py's limit is not {name}'s")
        one = os.path.join(self.work, "crop_data")
        synth_dataset.main(["--out", one, "--styles", "straight", "--count", "2",
                            "--size", "32x32", "--st", "", "--seed", "4"])
        err = self.script("train.py", "--data", one, "--styles", "", "--variant", "Small",
                          "--crop", "20", "--out", out)
        self.assertIn("--crop 20: Small halves the crop 3 times, so it must be a multiple of 8: "
                      "use 16", err)

    def test_split_leaves_a_training_frame(self):
        """A validation share that rounds to every frame leaves one to train
        on (the run failed drawing crops from none: numpy's "high <= 0")."""
        entries = [{"file": f"/x/straight_{i:04d}.exr", "style": "straight"} for i in range(2)]
        train_e, val_e = dataset.split_frames(entries, 0.9)
        self.assertEqual((len(train_e), len(val_e)), (1, 1))
        entries = [{"file": f"/x/wavy_{i:04d}.exr", "style": "wavy"} for i in range(10)]
        self.assertEqual([len(x) for x in dataset.split_frames(entries, 0.99)], [1, 9])
        self.assertEqual([len(x) for x in dataset.split_frames(entries, 0.1)], [9, 1])

    def test_other_scripts(self):
        err = self.script("stamp_range.py", self.cut, "--data", self.missing)
        self.assertIn("stamp_range.py: " + self.cut + ": tensor '", err)
        err = self.script("stamp_range.py", os.path.join(WEIGHTS, "small.safetensors"),
                          "--data", self.missing, "--out", os.path.join(self.work, "s.safetensors"))
        self.assertIn(f"stamp_range.py: {self.missing}: no such directory", err)
        out = os.path.join(self.missing, "s.safetensors")
        err = self.script("stamp_range.py", os.path.join(WEIGHTS, "small.safetensors"),
                          "--data", self.bad_manifest, "--out", out)
        self.assertIn(f"stamp_range.py: --out {out}: the directory {self.missing} does not exist",
                      err)
        # A directory for --out (with or without its slash): said before the
        # frames are measured, not a traceback from os.replace after them.
        for out in (self.work, self.work + os.sep):
            err = self.script("stamp_range.py", os.path.join(WEIGHTS, "small.safetensors"),
                              "--data", self.bad_manifest, "--out", out)
            self.assertIn(f"stamp_range.py: --out {out} is a directory: give the stamped copy's "
                          "file name", err)
        err = self.script("regime_table.py", f"x={self.missing}")
        self.assertIn(f"regime_table.py: {self.missing}: no such directory", err)
        err = self.script("eval_table.py", os.path.join(self.work, "none.json"))
        self.assertIn("none.json: No such file or directory", err)
        err = self.script("eval_table.py", os.path.join(self.bad_manifest, "manifest.json"))
        self.assertIn("manifest.json: not JSON (", err)


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--roundtrip", required=True)
    ap.add_argument("--hairfilter", required=True)
    ap.add_argument("--work", required=True)
    ARGS, rest = ap.parse_known_args()
    unittest.main(argv=[sys.argv[0], "-v", *rest])


if __name__ == "__main__":
    main()
