"""Copies evaluation frames with the results of two weights files computed in
PyTorch as the channels st1.* (the first) and st2.* (the second), so that
`hairfilter eval` scores networks no backend runs (the rows "stochastic
transparency 1 spp" and "2 spp" of its tables) with its own code.

  python3 weights/experiments/eval_rows.py [--stage split|frontback|fullres|aniso|sorted|ac]
      A.safetensors B.safetensors OUT_ROOT DIR...

Each DIR (a dataset directory with manifest.json) is copied to OUT_ROOT/<its
name> with every frame's channels, attributes and windows, plus the six new
channels. --stage installs an output stage of kernel_stages.py, the
branch of fullres_branch.py (`fullres`), the stage of aniso_kernel.py
(`aniso`), the depth-ordered samples of sorted_samples.py (`sorted`, for
both files) or the alpha-corrected input of ac_input.py (`ac`, for both
files; the frames need acst4.*) for files that need one. A network with the
estimate (KernelAC) reads it after the samples, as weights/train.py gives it. Frames that already hold st1.* or st2.* are refused."""
import argparse
import os
import shutil
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import OpenImageIO as oiio  # noqa: E402
import torch  # noqa: E402

import dataset  # noqa: E402
import hfnet  # noqa: E402
import aniso_kernel  # noqa: E402
import fullres_branch  # noqa: E402
import kernel_stages  # noqa: E402
import sorted_samples  # noqa: E402
import ac_input  # noqa: E402


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stage", choices=kernel_stages.STAGES + ("fullres", "aniso", "sorted", "ac"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("out_root")
    ap.add_argument("dirs", nargs="+")
    args = ap.parse_args(argv)
    if args.stage == "fullres":
        fullres_branch.install()
    elif args.stage == "aniso":
        aniso_kernel.install()
    elif args.stage == "sorted":
        sorted_samples.install()
    elif args.stage == "ac":
        ac_input.install()
    elif args.stage:
        kernel_stages.install(args.stage)
    torch.set_num_threads(args.threads)
    nets = [hfnet.load_model(p).eval() for p in (args.a, args.b)]
    for d in args.dirs:
        od = os.path.join(args.out_root, os.path.basename(d.rstrip("/")))
        os.makedirs(od, exist_ok=True)
        shutil.copy(os.path.join(d, "manifest.json"), od)
        for f in sorted(os.listdir(d)):
            if not f.endswith(".exr"):
                continue
            p = os.path.join(d, f)
            inp = oiio.ImageInput.open(p)
            if not inp:
                sys.exit(f"eval_rows.py: cannot read {p}: {oiio.geterror()}")
            spec = oiio.ImageSpec(inp.spec())
            names = list(spec.channelnames)
            if any(n.startswith(("st1.", "st2.")) for n in names):
                sys.exit(f"eval_rows.py: {p} already has st1.* or st2.* channels")
            data = np.asarray(inp.read_image(oiio.FLOAT), np.float32)
            data = data.reshape(spec.height, spec.width, len(names))
            inp.close()
            feat, _ = dataset.load_frame(p, spp=nets[0].cfg["spp"], dtype=np.float32)
            h, w = feat.shape[:2]
            x = hfnet.nhwc_to_nchw(feat.reshape(1, h, w, -1))
            if any(net.cfg.get("estimate") for net in nets):
                est = dataset.load_estimate(p, dtype=np.float32)
                x_est = torch.cat([x, hfnet.nhwc_to_nchw(est[None])], 1)
            extra, new = [], []
            with torch.no_grad():
                for k, net in ((1, nets[0]), (2, nets[1])):
                    y = net(x_est if net.cfg.get("estimate") else x)[0].numpy()
                    for c, name in enumerate(hfnet.OUTPUTS):
                        extra.append(y[c])
                        new.append(f"st{k}.{name}")
            spec.nchannels = len(names) + len(new)
            spec.channelnames = tuple(names + new)
            spec.set_format(oiio.FLOAT)
            out_path = os.path.join(od, f)
            o = oiio.ImageOutput.create(out_path)
            if not o or not o.open(out_path, spec):
                sys.exit(f"eval_rows.py: cannot write {out_path}: {oiio.geterror()}")
            o.write_image(np.ascontiguousarray(np.concatenate([data, np.stack(extra, -1)], -1)))
            o.close()
            print(out_path, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
