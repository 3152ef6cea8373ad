"""CPU time per frame of the model priors: ``python -m backend.bench.bench_prior_models [--out FILE]``.

Weights cannot be downloaded on the machines this project is tested on, and inference time does not
depend on weight values, so the benchmark builds the *real architectures* with random weights:

* Depth Anything V2 Small / Base / Large (transformers ``DepthAnythingForDepthEstimation``): DINOv2
  ViT-S/14, ViT-B/14, ViT-L/14 backbones (518 px position grid) with the DPT heads of the
  ``depth-anything/Depth-Anything-V2-{Small,Base,Large}-hf`` checkpoints and their image processor
  (shorter side to 518, multiple of 14, aspect kept). Parameter counts are checked against the
  published 24.8M / 97.5M / 335.3M (1%).
* Marigold IID appearance (diffusers ``MarigoldIntrinsicsPipeline``, ``prs-eth/marigold-iid-appearance-v1-1``
  layout): Stable Diffusion 2 UNet (in 12 = image + 2 target latents, out 8: albedo and material =
  roughness/metallicity), SD2 VAE, the OpenCLIP ViT-H text encoder (23 layers, 1024 wide; only run once
  for the empty prompt), DDIM (v-prediction, trailing spacing), 4 default steps at 768 px. The
  tokenizer is a stub (3 tokens): it only encodes the empty prompt.

Each model is saved to a temporary folder in the layout the loaders read and timed through the same
code path as ``igs priors --depth depth-anything:<dir>`` / ``--albedo marigold:<dir>``
(:func:`backend.priors.depth.make_depth_predictor`, :func:`backend.priors.albedo.make_albedo_predictor`),
``predict()`` on a random frame: one warm-up (which also loads the model), then the median of ``--runs``.
``--tiny`` builds tiny versions instead (a quick check of the script, not a measurement).
Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from backend.bench.bench_cli import error, number_list, write_result
from backend.core.errors import IGSError

# DINOv2 backbone (hidden, layers, heads, out_indices) and DPT head (neck sizes, fusion) of each checkpoint.
DAV2 = {
    "small": (384, 12, 6, [3, 6, 9, 12], [48, 96, 192, 384], 64, 24.8e6),
    "base": (768, 12, 12, [3, 6, 9, 12], [96, 192, 384, 768], 128, 97.5e6),
    "large": (1024, 24, 16, [5, 12, 18, 24], [256, 512, 1024, 1024], 256, 335.3e6),
}
MARIGOLD_STEPS, MARIGOLD_RES = 4, 768  # model_index.json of the Marigold v1-1 checkpoints


def n_params(model) -> int:
    return sum(p.numel() for p in model.parameters())


def build_depth_anything(size: str, path: Path, tiny: bool) -> int:
    """Save a randomly initialised Depth Anything V2 ``size`` checkpoint to ``path``; its parameter count."""
    import torch
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation, Dinov2Config
    from transformers.models.dpt.image_processing_pil_dpt import DPTImageProcessorPil

    hidden, layers, heads, out_idx, neck, fusion, published = DAV2[size]
    side = 518
    if tiny:
        hidden, layers, heads, out_idx, neck, fusion, side = 16, 4, 2, [1, 2, 3, 4], [8, 8, 16, 16], 8, 56
    torch.manual_seed(0)
    backbone = Dinov2Config(hidden_size=hidden, num_hidden_layers=layers, num_attention_heads=heads, mlp_ratio=4,
                            image_size=side, patch_size=14, out_indices=out_idx, apply_layernorm=True,
                            reshape_hidden_states=False)
    config = DepthAnythingConfig(backbone_config=backbone, reassemble_hidden_size=hidden, patch_size=14,
                                 neck_hidden_sizes=neck, fusion_hidden_size=fusion, head_hidden_size=4 if tiny else 32,
                                 depth_estimation_type="relative")
    model = DepthAnythingForDepthEstimation(config).eval()
    count = n_params(model)
    if not tiny and abs(count / published - 1) > 0.01:
        raise IGSError(f"Depth Anything V2 {size}: {count / 1e6:.1f}M parameters, published {published / 1e6:.1f}M")
    model.save_pretrained(path)
    processor = DPTImageProcessorPil(do_resize=True, size={"height": side, "width": side}, keep_aspect_ratio=True,
                                     ensure_multiple_of=14, do_pad=False, resample=3, do_rescale=True,
                                     rescale_factor=1 / 255, do_normalize=True,
                                     image_mean=[0.485, 0.456, 0.406], image_std=[0.229, 0.224, 0.225])
    processor.save_pretrained(path)
    cfg = path / "preprocessor_config.json"  # the published checkpoints name the class DPTImageProcessor
    cfg.write_text(json.dumps({**json.loads(cfg.read_text()), "image_processor_type": "DPTImageProcessor"}, indent=2))
    return count


def build_marigold(path: Path, tiny: bool) -> dict[str, int]:
    """Save a randomly initialised Marigold IID appearance pipeline to ``path``; parameters per component."""
    import torch
    from diffusers import AutoencoderKL, DDIMScheduler, MarigoldIntrinsicsPipeline, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    torch.manual_seed(0)
    targets = ["albedo", "material"]  # material = roughness, metallicity, unused
    if tiny:
        vae = AutoencoderKL(down_block_types=("DownEncoderBlock2D",) * 2, up_block_types=("UpDecoderBlock2D",) * 2,
                            block_out_channels=(8, 8), layers_per_block=1, latent_channels=4, norm_num_groups=4,
                            sample_size=32)
        unet = UNet2DConditionModel(sample_size=16, in_channels=4 * (1 + len(targets)), out_channels=4 * len(targets),
                                    layers_per_block=1, block_out_channels=(8, 16),
                                    down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
                                    up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=8,
                                    attention_head_dim=2, norm_num_groups=4)
        text_cfg = dict(hidden_size=8, intermediate_size=16, num_attention_heads=2, num_hidden_layers=1,
                        vocab_size=100, max_position_embeddings=8, projection_dim=8)
        steps, res = 2, 32
    else:  # Stable Diffusion 2 (stabilityai/stable-diffusion-2) configs
        vae = AutoencoderKL(in_channels=3, out_channels=3, down_block_types=("DownEncoderBlock2D",) * 4,
                            up_block_types=("UpDecoderBlock2D",) * 4, block_out_channels=(128, 256, 512, 512),
                            layers_per_block=2, latent_channels=4, norm_num_groups=32, act_fn="silu",
                            sample_size=768, scaling_factor=0.18215)
        unet = UNet2DConditionModel(sample_size=96, in_channels=4 * (1 + len(targets)), out_channels=4 * len(targets),
                                    layers_per_block=2, block_out_channels=(320, 640, 1280, 1280),
                                    down_block_types=("CrossAttnDownBlock2D",) * 3 + ("DownBlock2D",),
                                    up_block_types=("UpBlock2D",) + ("CrossAttnUpBlock2D",) * 3,
                                    cross_attention_dim=1024, attention_head_dim=(5, 10, 20, 20),
                                    use_linear_projection=True, norm_num_groups=32, flip_sin_to_cos=True,
                                    freq_shift=0, act_fn="silu")
        text_cfg = dict(hidden_size=1024, intermediate_size=4096, num_attention_heads=16, num_hidden_layers=23,
                        vocab_size=49408, max_position_embeddings=77, projection_dim=512, hidden_act="gelu")
        steps, res = MARIGOLD_STEPS, MARIGOLD_RES
    scheduler = DDIMScheduler(num_train_timesteps=1000, prediction_type="v_prediction", timestep_spacing="trailing",
                              beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012, clip_sample=False,
                              set_alpha_to_one=False, steps_offset=1)
    text = CLIPTextModel(CLIPTextConfig(**text_cfg, bos_token_id=0, eos_token_id=1, pad_token_id=1))
    tok_dir = path.parent / f"{path.name}-tok"
    tok_dir.mkdir()
    (tok_dir / "vocab.json").write_text(json.dumps({"<|startoftext|>": 0, "<|endoftext|>": 1, "a</w>": 2}))
    (tok_dir / "merges.txt").write_text("#version: 0.2\n")
    tokenizer = CLIPTokenizer(vocab_file=str(tok_dir / "vocab.json"), merges_file=str(tok_dir / "merges.txt"),
                              model_max_length=text_cfg["max_position_embeddings"])
    props = {"target_names": targets, "albedo": {"prediction_space": "srgb"},
             "material": {"sub_target_names": ["roughness", "metallicity", None]},
             "roughness": {"prediction_space": "linear"}, "metallicity": {"prediction_space": "linear"}}
    MarigoldIntrinsicsPipeline(unet=unet, vae=vae, scheduler=scheduler, text_encoder=text, tokenizer=tokenizer,
                               prediction_type="intrinsics", target_properties=props, default_denoising_steps=steps,
                               default_processing_resolution=res).save_pretrained(path)
    return {"unet": n_params(unet), "vae": n_params(vae), "text_encoder": n_params(text)}


def frame(width: int, height: int) -> np.ndarray:
    return (np.random.default_rng(0).random((height, width, 3)) * 255).astype(np.uint8)


def timed(pred, img: np.ndarray) -> tuple[float, np.ndarray]:
    from backend.priors.folder import PriorFrame

    t = time.perf_counter()
    out = pred.predict(PriorFrame(0, "frame_0000.png", "frame_0000.png", None), img)
    return time.perf_counter() - t, out


def bench_depth(sizes: list[str], frames: list[tuple[int, int]], runs: int, tiny: bool, work: Path,
                log) -> list[dict[str, Any]]:
    from backend.priors.depth import DepthOptions, make_depth_predictor

    rows = []
    for size in sizes:
        folder = work / f"dav2-{size}"
        count = build_depth_anything(size, folder, tiny)
        pred = make_depth_predictor(f"depth-anything:{folder}", None, 1, None, DepthOptions(device="cpu"))
        row: dict[str, Any] = {"model": f"Depth Anything V2 {size.capitalize()}", "parameters": count,
                               "steps": None, "seconds": {}, "processing": {}, "runs": runs}
        for w, h in frames:
            img = frame(w, h)
            timed(pred, img)  # warm-up (the first one also loads the model)
            shape = tuple(pred.processor(images=img, return_tensors="pt")["pixel_values"].shape[-2:])
            times = [timed(pred, img)[0] for _ in range(runs)]
            row["seconds"][f"{w}x{h}"] = round(statistics.median(times), 3)
            row["processing"][f"{w}x{h}"] = f"{shape[1]}x{shape[0]}"
            log(f"{row['model']} {w}x{h}: processed at {shape[1]}x{shape[0]}, runs {[round(t, 2) for t in times]} s")
        rows.append(row)
        del pred
    return rows


def bench_marigold(steps_list: list[int], mframes: list[tuple[int, int]], warmup: bool, tiny: bool, work: Path,
                   log) -> list[dict[str, Any]]:
    from backend.priors.albedo import AlbedoOptions, make_albedo_predictor

    folder = work / "marigold-iid-appearance"
    t = time.perf_counter()
    counts = build_marigold(folder, tiny)
    log(f"Marigold built and saved in {time.perf_counter() - t:.0f} s: {counts}")
    default_steps = json.loads((folder / "model_index.json").read_text())["default_denoising_steps"]
    res = json.loads((folder / "model_index.json").read_text())["default_processing_resolution"]
    first = make_albedo_predictor(f"marigold:{folder}", None, 1, None, AlbedoOptions(device="cpu", steps=1))
    t = time.perf_counter()
    first._load()
    log(f"Marigold loaded in {time.perf_counter() - t:.0f} s")
    # One warm-up, 1 step on the first frame: computes the empty-prompt embedding, touches every module.
    log(f"Marigold warm-up (1 step, {mframes[0][0]}x{mframes[0][1]}): {timed(first, frame(*mframes[0]))[0]:.1f} s")
    rows = []
    for steps in steps_list:
        pred = make_albedo_predictor(f"marigold:{folder}", None, 1, None, AlbedoOptions(device="cpu", steps=steps))
        pred.pipe, pred.device = first.pipe, first.device  # the loaded pipeline; predict() is the users' code path
        row: dict[str, Any] = {"model": "Marigold IID appearance", "parameters": counts["unet"],
                               "parameters_all": sum(counts.values()), "steps": steps or default_steps,
                               "seconds": {}, "processing": {}, "runs": 1}
        for w, h in mframes:
            img = frame(w, h)
            if warmup:
                timed(pred, img)
            s, out = timed(pred, img)
            long_side = res
            row["seconds"][f"{w}x{h}"] = round(s, 3)
            row["processing"][f"{w}x{h}"] = (f"{long_side}x{round(h * long_side / w)}" if w >= h
                                             else f"{round(w * long_side / h)}x{long_side}")
            log(f"Marigold {steps or default_steps} steps {w}x{h}: {s:.1f} s (finite output: {np.isfinite(out).all()})")
        rows.append(row)
    return rows


def table(rows: list[dict[str, Any]], frames: list[tuple[int, int]]) -> str:
    keys = [f"{w}x{h}" for w, h in frames]
    head = ["model", "parameters", "processing resolution", "steps"] + [f"s/frame {k}" for k in keys]
    out = [" | ".join(head), " | ".join("-" * len(x) for x in head)]
    for r in rows:
        proc = ", ".join(sorted(set(r["processing"].values()), key=list(r["processing"].values()).index))
        out.append(" | ".join([r["model"], f"{r['parameters'] / 1e6:.1f}M", proc, str(r["steps"] or "-")]
                              + [f"{r['seconds'][k]:.2f}" if k in r["seconds"] else "-" for k in keys]))
    return "\n".join(out)


def parse_frames(text: str) -> list[tuple[int, int]]:
    out = []
    for item in text.split(","):
        w, _, h = item.partition("x")
        if not (w.isdigit() and h.isdigit()) or int(w) < 14 or int(h) < 14:
            raise IGSError(f"--frames: expected WIDTHxHEIGHT[,...], got {text!r}")
        out.append((int(w), int(h)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_prior_models", description=__doc__.split("\n\n")[0])
    ap.add_argument("--depth", default="small,base,large", help="Depth Anything V2 sizes, or 'none' (default all)")
    ap.add_argument("--frames", default="1280x720,640x480", help="depth frame sizes (default 1280x720,640x480)")
    ap.add_argument("--runs", type=int, default=3, help="timed depth runs per frame after a warm-up (median; default 3)")
    ap.add_argument("--marigold-steps", default="0,1",
                    help="Marigold denoising steps per row, 0 = the checkpoint's default (default 0,1); 'none' skips")
    ap.add_argument("--marigold-frames", default="1280x720", help="Marigold frame sizes (default 1280x720)")
    ap.add_argument("--marigold-warmup", action="store_true",
                    help="a warm-up before each timed Marigold prediction (default: one 1-step warm-up in all)")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    ap.add_argument("--tiny", action="store_true", help="tiny random models: checks the script, measures nothing")
    ap.add_argument("--out", default="bench_prior_models.json", help="JSON output (default bench_prior_models.json)")
    args = ap.parse_args(argv)
    try:
        import torch

        torch.set_num_threads(args.threads)
        sizes = [] if args.depth == "none" else [s for s in args.depth.split(",") if s]
        if any(s not in DAV2 for s in sizes):
            raise IGSError(f"--depth: expected sizes among {', '.join(DAV2)} or 'none', got {args.depth!r}")
        frames = parse_frames(args.frames)
        mframes = parse_frames(args.marigold_frames)
        steps = [] if args.marigold_steps == "none" else number_list(args.marigold_steps, int, 0,
                                                                      "--marigold-steps must be integers >= 0")
        if args.runs < 1:
            raise IGSError(f"--runs must be at least 1, got {args.runs}")

        def log(msg: str) -> None:
            print(msg, flush=True)

        with tempfile.TemporaryDirectory(prefix="igs-bench-prior-models-") as tmp:
            rows = bench_depth(sizes, frames, args.runs, args.tiny, Path(tmp), log)
            if steps:
                rows += bench_marigold(steps, mframes, args.marigold_warmup, args.tiny, Path(tmp), log)
    except (IGSError, ValueError) as e:
        return error("bench_prior_models", e)
    import diffusers
    import torch
    import transformers

    result = {"tiny": args.tiny, "weights": "random (the real architectures; time does not depend on weight values)",
              "device": "cpu", "threads": torch.get_num_threads(), "cpu_count": os.cpu_count(),
              "cpu": platform.processor() or platform.machine(), "torch": torch.__version__,
              "transformers": transformers.__version__, "diffusers": diffusers.__version__,
              "depth_runs": args.runs, "results": rows}
    all_frames = list(dict.fromkeys(frames + mframes))
    return write_result(table(rows, all_frames), args.out, result)


if __name__ == "__main__":
    sys.exit(main())
