#!/usr/bin/python3
"""The safetensors header checks of weights/hfnet.py and of the C loader,
on the same files: duplicate keys at any level, "__metadata__" of the
wrong type, a header that does not start with '{', and tensor ranges that
do not tile the data (overlapping, a gap, bytes after the last) are refused
by both, with the key or the bytes named.

    test_safetensors.py --roundtrip BUILD/tests/train/weights_roundtrip --work DIR

Exits 77 (skipped) when torch or numpy is missing.
"""
import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "weights"))
FIELD = os.path.join(HERE, "..", "data", "field")

try:
    import numpy  # noqa: F401
    import torch  # noqa: F401
except ImportError as e:  # pragma: no cover - depends on the machine
    print(f"train.safetensors skipped: {e} (install python3-torch python3-numpy)")
    sys.exit(77)

import hfnet  # noqa: E402

ARGS = None


def c_loader(path):
    """(exit status, stderr) of the C loader on path."""
    r = subprocess.run([ARGS.roundtrip, path, path + ".out"], capture_output=True, text=True)
    return r.returncode, r.stderr


class Header(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        os.makedirs(ARGS.work, exist_ok=True)
        cls.valid = os.path.join(ARGS.work, "small.safetensors")
        cfg = hfnet.variant_config("Small")
        torch.manual_seed(3)
        hfnet.save_safetensors(cls.valid, cfg, hfnet.HairNet(cfg).state_dict())
        with open(cls.valid, "rb") as f:
            data = f.read()
        (n,) = struct.unpack("<Q", data[:8])
        cls.header, cls.rest = data[8:8 + n].decode(), data[8 + n:]

    def edited(self, name, old, new, rest=None, prefix=b""):
        """The valid file with the header's first old replaced by new (and
        its data replaced by rest, prefix put before the header's JSON)."""
        self.assertIn(old, self.header)
        h = prefix + self.header.replace(old, new, 1).encode()
        path = os.path.join(ARGS.work, name)
        with open(path, "wb") as f:
            f.write(struct.pack("<Q", len(h)) + h + (self.rest if rest is None else rest))
        return path

    def offsets(self, tensor):
        """The [begin, end] text of tensor's data_offsets in the header."""
        start = self.header.index('"data_offsets":', self.header.index(f'"{tensor}"'))
        return self.header[start:self.header.index("]", start) + 1]

    def test_byte_order_mark(self):
        self.refused(self.edited("bom.safetensors", "{", "{", prefix=b"\xef\xbb\xbf"),
                     ["does not start with '{'"])

    def test_overlapping_tensors(self):
        # enc0.bias and the last bias of the same size share their bytes.
        def size(k):
            o = self.offsets(k)
            return int(o[o.index(",") + 1:-1]) - int(o[o.index("[") + 1:o.index(",")])
        bias = self.offsets("enc0.bias")
        other = [k for k in hfnet.load_safetensors(self.valid)[1]
                 if k != "enc0.bias" and k.endswith(".bias") and size(k) == size("enc0.bias")][0]
        self.refused(self.edited("overlap.safetensors", self.offsets(other), bias),
                     ["overlap", "each tensor owns its bytes"])

    def test_gap_between_tensors(self):
        # The last tensor moved 4 bytes on, with 4 bytes more data before it.
        ranges = []
        for k in hfnet.load_safetensors(self.valid)[1]:
            t = self.offsets(k)
            ranges.append((int(t[t.index("[") + 1:t.index(",")]), int(t[t.index(",") + 1:-1]), k))
        b, e, last = max(ranges)
        path = self.edited("gap.safetensors", self.offsets(last),
                           f'"data_offsets":[{b + 4},{e + 4}]',
                           rest=self.rest[:b] + b"\0" * 4 + self.rest[b:])
        self.refused(path, [f"bytes [{b}, {b + 4}) of the data belong to no tensor"])

    def test_bytes_after_last_tensor(self):
        path = self.edited("trailing.safetensors", "{", "{", rest=self.rest + b"\0" * 16)
        self.refused(path, ["16 bytes after the last tensor"])

    def test_cut_short(self):
        """A file cut short (a copy that stopped) is named as such by the
        Python reader, not as "-N bytes after the last tensor"; the C
        loader names the tensor whose offsets pass the end."""
        path = self.edited("cut.safetensors", "{", "{", rest=self.rest[:-100])
        with self.assertRaises(ValueError) as e:
            hfnet.load_safetensors(path)
        self.assertIn("end past the", str(e.exception))
        self.assertIn("the file is cut short", str(e.exception))
        self.assertNotIn("after the last tensor", str(e.exception))
        rc, err = c_loader(path)
        self.assertEqual(rc, 1, err)
        self.assertIn("end past the", err)
        self.assertIn("(a truncated file?)", err)

    def test_checkpoint_for_weights(self):
        """A PyTorch checkpoint given for weights (train.py --init
        RUN/checkpoint.pt) is named as one, with how to export its weights,
        by both readers; it was "header length N exceeds file size"."""
        path = os.path.join(ARGS.work, "checkpoint.pt")
        torch.save({"model": {}}, path)
        self.refused(path, ["a zip archive, not a safetensors file: a PyTorch checkpoint",
                            "--export W.safetensors"])

    def test_tensors_and_metadata_the_network_does_not_match(self):
        """weights/FORMAT.md: hfnet.load_safetensors refuses, as the C
        loader does, a tensor missing, extra or of another shape and
        metadata whose features or input channels are not the network's;
        it took them, and train.py --init failed later in load_state_dict
        (or trained on a wrong features list)."""
        cfg = hfnet.variant_config("Small")
        sd = hfnet.HairNet(cfg).state_dict()
        extra = dict(sd, **{"extra.weight": torch.zeros(3)})
        missing = {k: v for k, v in sd.items() if k != "enc0.bias"}
        shape = dict(sd, **{"enc0.bias": torch.zeros(5)})
        features = dict(cfg, features=["color", "highlight", "alpha", "depth", "tangent.x", "x"])
        inputs = dict(cfg, in_channels=23)
        for name, c, state, words in (
                ("extra", cfg, extra, "not of this network: extra.weight"),
                ("missing", cfg, missing, "missing enc0.bias"),
                ("shape", cfg, shape, "tensor 'enc0.bias': shape [5], the configuration needs [16]"),
                ("features", features, sd, "metadata: 'features' is"),
                ("inputs", inputs, sd, "in_channels 23, but spp 4 x 6 features make 24")):
            path = os.path.join(ARGS.work, f"mismatch_{name}.safetensors")
            hfnet.save_safetensors(path, c, state)
            with self.assertRaises(ValueError, msg=name) as e:
                hfnet.load_safetensors(path)
            self.assertIn(words, str(e.exception))
            rc, err = c_loader(path)
            self.assertEqual(rc, 1, f"{name}: {err}")

    def refused(self, path, words):
        """Both readers refuse path, naming every word of words."""
        with self.assertRaises(ValueError) as e:
            hfnet.load_safetensors(path)
        for w in words:
            self.assertIn(w, str(e.exception))
        rc, err = c_loader(path)
        self.assertEqual(rc, 1, err)
        for w in words:
            self.assertIn(w, err)

    def test_nonfinite_weight(self):
        """A NaN or infinite weight is refused by both readers, naming the
        tensor: loaded, it made every output pixel it reached NaN."""
        first = min((int(self.offsets(k)[self.offsets(k).index("[") + 1:
                                         self.offsets(k).index(",")]), k)
                    for k in hfnet.load_safetensors(self.valid)[1])[1]
        for v in (float("nan"), float("inf"), float("-inf")):
            rest = struct.pack("<f", v) + self.rest[4:]
            self.refused(self.edited("nonfinite.safetensors", "{", "{", rest=rest),
                         [f"tensor '{first}': value 0 of", "is not finite (NaN or infinite)"])

    def test_malformed_tensor_fields(self):
        """A tensor field of another JSON type (a shape that is a number, a
        dtype that is a list, offsets that are negative) or a header nested
        thousands deep is a ValueError naming the file, as the C loader
        refuses it; the Python reader raised TypeError or RecursionError."""
        deep = "[" * 5000 + "]" * 5000
        cases = [("shape.safetensors", '"shape":[', '"shape":5,"x":['),
                 ("dtype.safetensors", '"dtype":"F32"', '"dtype":["F32"]'),
                 ("offsets.safetensors", '"data_offsets":[0,', '"data_offsets":[-4,'),
                 ("deep.safetensors", '{"__metadata__":', '{"x":' + deep + ',"__metadata__":'),
                 ("deep_cfg.safetensors", '{\\"name', '{\\"x\\":' + deep + ',\\"name')]
        for name, old, new in cases:
            with self.subTest(name):
                path = self.edited(name, old, new)
                try:
                    hfnet.load_safetensors(path)
                    self.fail(f"{name} loaded")
                except ValueError as e:
                    self.assertIn(path, str(e))
                rc, err = c_loader(path)
                self.assertEqual(rc, 1, err)

    def test_hairfilter_counts_and_bom(self):
        """The 'hairfilter' string's counts written as 4.0 or 32.0, and a
        byte order mark before its JSON, are refused by both readers (the C
        loader took them: cJSON reads 4.0 as 4 and skips a mark)."""
        for name, old, new, word in [
                ("spp.safetensors", '\\"spp\\": 4', '\\"spp\\": 4.0', "'spp'"),
                ("levels.safetensors", '\\"levels\\": [16', '\\"levels\\": [16.0', "'levels'"),
                ("levels_exp.safetensors", '\\"levels\\": [16', '\\"levels\\": [1.6e1', "'levels'"),
                ("bom.safetensors", '"hairfilter":"{', '"hairfilter":"\ufeff{', "metadata 'hairfilter'")]:
            with self.subTest(name):
                self.refused(self.edited(name, old, new), [word])

    def test_name_longer_than_the_c_loader_takes(self):
        """A variant name over 63 bytes (UTF-8) is refused by both readers;
        hfnet.load_safetensors took it, and hairfilterd refused the file."""
        for name, ok in (("x" * 63, True), ("x" * 64, False), ("\u00e9" * 32, False)):
            with self.subTest(len=len(name.encode())):
                path = self.edited("name.safetensors", '\\"name\\": \\"Small\\"',
                                   '\\"name\\": \\"' + name + '\\"')
                if ok:
                    self.assertEqual(hfnet.load_safetensors(path)[0]["name"], name)
                    self.assertEqual(c_loader(path)[0], 0)
                else:
                    self.refused(path, ["'name' missing or longer than 63 bytes"])

    def test_input_range_checked_alike(self):
        """An 'input_range' the C loader refuses is refused by
        hfnet.load_safetensors in its words; it took any JSON object."""
        def with_range(name, text):
            return self.edited(name, '"__metadata__":{',
                               '"__metadata__":{"input_range":' + json.dumps(text) + ',')
        for name, text, word in [
                ("r_def.safetensors", '{"spp": 4}', "input_range: no 'definition' number"),
                ("r_spp.safetensors", '{"definition": 1, "spp": 2, "frames": 3, '
                 '"hair_fraction": [0.1, 0.2]}', "input_range: 'spp' must be the variant's 4"),
                ("r_frames.safetensors", '{"definition": 1, "spp": 4, "frames": 0, '
                 '"hair_fraction": [0.1, 0.2]}', "input_range: 'frames' must be a count >= 1"),
                ("r_order.safetensors", '{"definition": 1, "spp": 4, "frames": 3, '
                 '"hair_fraction": [0.2, 0.1]}', "'hair_fraction' must be [low, high]"),
                ("r_none.safetensors", '{"definition": 1, "spp": 4, "frames": 3}',
                 "input_range: no statistic has a range")]:
            with self.subTest(name):
                self.refused(with_range(name, text), [word])
        # NaN, which Python's json reads and cJSON does not: refused by both.
        path = with_range("r_nan.safetensors", '{"definition": 1, "spp": 4, "frames": 3, '
                          '"hair_fraction": [NaN, 0.2]}')
        with self.assertRaises(ValueError):
            hfnet.load_safetensors(path)
        self.assertEqual(c_loader(path)[0], 1)
        # A range of another definition is left unused by both.
        path = with_range("r_other.safetensors", '{"definition": 99}')
        hfnet.load_safetensors(path)
        self.assertEqual(c_loader(path)[0], 0)

    def test_valid_loads_in_both(self):
        cfg, sd = hfnet.load_safetensors(self.valid)
        self.assertEqual(cfg["name"], "Small")
        self.assertEqual(c_loader(self.valid)[0], 0)

    def test_save_replaces_whole(self):
        """save_safetensors writes beside the file and renames: a reader that
        has the old file open reads it whole to the end (written in place,
        it read the new file's bytes after the first 100), and no temporary
        is left behind."""
        path = os.path.join(ARGS.work, "replaced.safetensors")
        shutil.copy(self.valid, path)
        with open(self.valid, "rb") as f:
            old = f.read()
        cfg = hfnet.variant_config("Shallow")
        with open(path, "rb") as reader:
            head = reader.read(100)
            hfnet.save_safetensors(path, cfg, hfnet.HairNet(cfg).state_dict())
            self.assertEqual(head + reader.read(), old)
        self.assertEqual(hfnet.load_safetensors(path)[0]["name"], "Shallow")
        self.assertFalse(os.path.exists(path + ".tmp"))

    def test_field_case_duplicate_metadata(self):
        self.refused(os.path.join(FIELD, "weights-duplicate-metadata.safetensors"),
                     ["duplicate key '__metadata__'"])

    def test_duplicate_metadata_generated(self):
        meta = self.header[:self.header.index(',"enc0.weight"')]
        other = meta.replace('\\"unet\\"', '\\"residual\\"').replace('{"__metadata__"', '"__metadata__"')
        # '{"__metadata__":{...},"__metadata__":{...residual...},"enc0.weight":...'
        self.refused(self.edited("dup_meta.safetensors", ',"enc0.weight"', "," + other + ',"enc0.weight"'),
                     ["duplicate key '__metadata__'"])

    def test_duplicate_tensor(self):
        start = self.header.index('"enc0.bias"')
        end = self.header.index("}", start) + 1
        entry = self.header[start:end]
        self.refused(self.edited("dup_tensor.safetensors", entry, entry + "," + entry),
                     ["duplicate key 'enc0.bias'"])

    def test_duplicate_inside_tensor(self):
        self.refused(self.edited("dup_dtype.safetensors", '"dtype":"F32"', '"dtype":"F32","dtype":"F16"'),
                     ["duplicate key 'dtype'"])

    def test_duplicate_inside_hairfilter(self):
        self.refused(self.edited("dup_levels.safetensors", '\\"spp\\": 4', '\\"spp\\": 4, \\"spp\\": 1'),
                     ["hairfilter", "duplicate key 'spp'"])

    def test_header_text(self):
        """A header with bytes that are not UTF-8, or a \\u0000 escape (which
        C cuts a name at: "enc0.bias\\u0000x" would load as enc0.bias), is
        refused by both readers, in the header and in the 'hairfilter'
        string alike."""
        self.refused(self.edited("nul_name.safetensors", '"enc0.bias"', '"enc0.bias\\u0000x"'),
                     ["\\u0000"])
        self.refused(self.edited("nul_meta.safetensors", '"__metadata__":{',
                                 '"__metadata__":{"note":"a\\u0000",'), ["\\u0000"])
        self.refused(self.edited("nul_hairfilter.safetensors", '\\"spp\\": 4',
                                 '\\"spp\\": 4, \\"x\\\\u0000\\": 1'),
                     ["hairfilter", "\\u0000"])
        for name, raw in [("latin1", b"\xe9"), ("surrogate", b"\xed\xa0\x80"),
                          ("overlong", b"\xc0\xaf")]:
            h = self.header.encode().replace(b'"__metadata__":{',
                                             b'"__metadata__":{"note":"' + raw + b'",', 1)
            path = os.path.join(ARGS.work, f"text_{name}.safetensors")
            with open(path, "wb") as f:
                f.write(struct.pack("<Q", len(h)) + h + self.rest)
            self.refused(path, ["UTF-8"])
        # Shapes and offsets as fractions: integers to == , not to the
        # safetensors reference reader; both loaders refuse them.
        start = self.header.index('"shape":[', self.header.index('"enc0.weight"')) + 9
        first = self.header[start:self.header.index(",", start)]
        self.refused(self.edited("shape_float.safetensors", f'"shape":[{first},',
                                 f'"shape":[{first}.0,'), ["shape holds", "not an integer"])
        self.refused(self.edited("offset_float.safetensors", '"data_offsets":[0,',
                                 '"data_offsets":[0.0,'), ["data_offsets holds", "not an integer"])
        # An escaped backslash before u0000 is no NUL: both load it.
        path = self.edited("escaped_backslash.safetensors", '"__metadata__":{',
                           '"__metadata__":{"note":"\\\\u0000",')
        hfnet.load_safetensors(path)
        self.assertEqual(c_loader(path)[0], 0)

    def test_json_python_took_and_c_refused(self):
        """NaN and Infinity (not JSON, which Python's json reads), a lone
        half of a UTF-16 surrogate pair (no character, which Python's json
        reads into a str that cannot be encoded) and true in a shape (1 to
        Python's ==) are refused by both readers, saying what they are;
        hfnet.load_safetensors took the first and the last, and raised
        UnicodeEncodeError, naming no file, on the second."""
        for where, old, new in [
                ("header", '"__metadata__":{', '"zz":NaN,"__metadata__":{'),
                ("hairfilter", '\\"spp\\": 4', '\\"spp\\": 4, \\"x\\": Infinity'),
                ("hairfilter", '\\"spp\\": 4', '\\"spp\\": 4, \\"x\\": -Infinity')]:
            path = self.edited(f"constant_{where}.safetensors", old, new)
            with self.assertRaises(ValueError) as e:
                hfnet.load_safetensors(path)
            self.assertIn("is not a JSON number", str(e.exception))
            rc, err = c_loader(path)
            self.assertEqual(rc, 1, err)
            self.assertIn("not valid JSON", err)
        for i, (old, new) in enumerate([
                ('\\"name\\": \\"Small\\"', '\\"name\\": \\"a\\\\ud800b\\"'),
                ('\\"name\\": \\"Small\\"', '\\"name\\": \\"a\\\\udc00\\"'),
                ('"enc0.bias"', '"enc0.bias\\ud83dx"'),
                ('"__metadata__":{', '"__metadata__":{"note":"\\uDBFF\\u0041",')]):
            self.refused(self.edited(f"surrogate{i}.safetensors", old, new),
                         ["half of a UTF-16 surrogate pair"])
        # A pair is one character: both load it.
        path = self.edited("pair.safetensors", '"__metadata__":{',
                           '"__metadata__":{"note":"\\ud83d\\ude00",')
        hfnet.load_safetensors(path)
        self.assertEqual(c_loader(path)[0], 0)
        start = self.header.index('"shape":[', self.header.index('"enc0.bias"')) + 9
        end = self.header.index("]", start)
        self.refused(self.edited("shape_true.safetensors", self.header[start - 9:end + 1],
                                 '"shape":[true]'), ["shape holds true, not an integer"])

    def test_huge_file_refused_before_it_is_read(self):
        """A file over the 2 GiB either loader reads (a sparse 3 GiB file
        here) is refused by its size before it is read, by both; the Python
        reader read it whole into memory (run here under a 1 GiB address
        space limit, where that fails)."""
        path = os.path.join(ARGS.work, "huge.safetensors")
        with open(path, "wb") as f:
            f.write(struct.pack("<Q", 2) + b"{}")
            f.truncate(3 << 30)
        code = ("import resource, sys\n"
                "resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))\n"
                f"sys.path.insert(0, {os.path.join(HERE, '..', '..', 'weights')!r})\n"
                "import safetensors_header\n"
                "try:\n"
                f"    safetensors_header.read_header({path!r})\n"
                "except ValueError as e:\n"
                "    print(e)\n")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertIn(f"{path}: larger than the 2147483648 bytes a weights file may have",
                      r.stdout)
        rc, err = c_loader(path)
        self.assertEqual(rc, 1, err)
        self.assertIn("larger than the 2147483648 bytes", err)
        os.remove(path)

    def test_bytes_after_json(self):
        """Bytes after a JSON object (the header's, the 'hairfilter' and
        'input_range' strings') are refused by both readers; JSON's
        whitespace after the header is not."""
        end = self.header.rstrip(" ")
        self.refused(self.edited("after_header.safetensors", end, end + "x"), [])
        self.refused(self.edited("after_header_ctl.safetensors", end, end + "\x01"), [])
        self.refused(self.edited("after_hairfilter.safetensors", ']}"}', ']}x"}'),
                     ["hairfilter"])
        rng = '"input_range":"{\\"definition\\": 1, \\"spp\\": 4}x",'
        self.refused(self.edited("after_range.safetensors", '"__metadata__":{',
                                 '"__metadata__":{' + rng), ["input_range"])
        path = self.edited("after_header_ws.safetensors", end, end + " \t\r\n ")
        hfnet.load_safetensors(path)
        rc, err = c_loader(path)
        self.assertEqual(rc, 0, err)

    def test_metadata_wrong_types(self):
        path = self.edited("meta_number.safetensors", '"__metadata__":{', '"__metadata__":{"epoch":3,')
        self.refused(path, ["'__metadata__.epoch'", "string"])
        path = self.edited("meta_array.safetensors", '"__metadata__":{', '"__metadata__":{"tags":["a"],')
        self.refused(path, ["'__metadata__.tags'"])
        meta_end = self.header.index(',"enc0.weight"')
        whole = self.header[len('{"__metadata__":'):meta_end]
        path = self.edited("meta_string.safetensors", '"__metadata__":' + whole, '"__metadata__":"x"')
        self.refused(path, ["'__metadata__'", "object"])


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--roundtrip", required=True)
    ap.add_argument("--work", required=True)
    ARGS, rest = ap.parse_known_args()
    unittest.main(argv=[sys.argv[0]] + rest, verbosity=2)


if __name__ == "__main__":
    main()
