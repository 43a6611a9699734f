"""Where a network's output of one frame loses SSIM against the frame's own
samples, and what it does to dark, opaque hair: the figures of
weights/base.md, "The SSIM term and sRGB-encoded errors".

  hairfilter infer --backend cpu --weights W --in FRAME.exr --out OUT.exr
  python3 weights/experiments/dark_hair.py FRAME.exr OUT.exr

Prints, on the frame's hair pixels (ground-truth alpha > 0) whose SSIM
window lies inside the frame, the SSIM of the network's composite and of
the samples' estimate (the `input` row of `hairfilter eval`) against the
truth's, composited with the evaluation's look (train.EVAL_LOOK, train.py's
SSIM window), and the share of the deficit in pixels without a highlight
(truth < 0.02) and in opaque ones (truth alpha >= 0.99); the frame's SSIM
with the truth's colour factor, or alpha, in place of the network's; and,
over the dark, fully covered pixels (truth alpha > 0.999 and colour factor
< 0.1, all samples covered), the truth's and the network's median colour
factor, the share of the network's at or below 0 (shown black) and of its
alpha below 0.99, the 90th percentiles and the median errors of the
network's colour factor and of the estimate's."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import torch  # noqa: E402

import dataset  # noqa: E402
import train  # noqa: E402


def channels(path):
    names, data = dataset.read_exr(path)
    return {n: data[..., i] for i, n in enumerate(names)}


def main(argv):
    if len(argv) != 2:
        sys.exit("usage: dark_hair.py FRAME.exr OUT.exr (OUT: `hairfilter infer` of FRAME)")
    g, o = channels(argv[0]), channels(argv[1])
    spp = dataset.count_spp(list(g))
    looks = [torch.tensor(v).view(1, 3, 1, 1) for v in train.EVAL_LOOK]

    def comp(c, h, a):
        return train.composite(torch.from_numpy(np.stack([c, h, a]))[None], *looks)

    cov = np.stack([g[f"S{k}.alpha"] > 0 for k in range(spp)])
    n = cov.sum(0).clip(1)
    est = [(np.stack([g[f"S{k}.{c}"] for k in range(spp)]) * cov).sum(0) / n
           for c in ("color", "highlight")] + [cov.mean(0)]
    truth = [g["gt.color"], g["gt.highlight"], g["gt.alpha"]]
    out = [o["color"], o["highlight"], o["alpha"]]
    ct = comp(*truth)

    def ssim(c, h, a):
        return train.ssim_map(comp(c, h, a), ct)[0].numpy()

    r = train.SSIM_RADIUS
    inner = (slice(r, -r), slice(r, -r))
    hair = truth[2][inner] > 0
    s_net, s_in = ssim(*out), ssim(*est)
    deficit = (s_in - s_net)[hair].sum()
    print(f"hair pixels {hair.sum()}: SSIM network {s_net[hair].mean():.3f}, "
          f"own input {s_in[hair].mean():.3f}")
    for what, m in (("without a highlight", truth[1][inner] < 0.02),
                    ("opaque", truth[2][inner] >= 0.99)):
        mm = hair & m
        print(f"  {what}: {100 * mm.sum() / hair.sum():.0f}% of hair pixels, "
              f"{100 * (s_in - s_net)[mm].sum() / deficit:.0f}% of the deficit")
    for what, k in (("colour factor", 0), ("alpha", 2)):
        swapped = list(out)
        swapped[k] = truth[k]
        print(f"  with the truth's {what}: SSIM {ssim(*swapped)[hair].mean():.3f}")
    dark = (truth[2] > 0.999) & cov.all(0) & (truth[0] < 0.1)
    if dark.any():
        c = out[0][dark]
        print(f"dark, fully covered pixels {dark.sum()}: colour factor median truth "
              f"{np.median(truth[0][dark]):.3f}, network {np.median(c):.3f}; "
              f"at or below 0 {100 * (c <= 0).mean():.0f}%; "
              f"alpha below 0.99 {100 * (out[2][dark] < 0.99).mean():.0f}%")
        t = truth[0][dark]
        print(f"  90th percentile truth {np.percentile(t, 90):.3f}, network "
              f"{np.percentile(c, 90):.3f}; median error network {np.median(abs(c - t)):.3f}, "
              f"own input {np.median(abs(est[0][dark] - t)):.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
