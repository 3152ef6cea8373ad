"""Tiny random-weight prior models (Depth Anything, Marigold) saved in the hub's layout, for the priors tests."""

from __future__ import annotations

import json

import torch


def tiny_depth_anything(path):
    from transformers import DepthAnythingConfig, DepthAnythingForDepthEstimation, Dinov2Config
    from transformers.models.dpt.image_processing_pil_dpt import DPTImageProcessorPil

    torch.manual_seed(0)
    backbone = Dinov2Config(hidden_size=16, num_hidden_layers=4, num_attention_heads=2, mlp_ratio=2, image_size=56,
                            patch_size=14, out_indices=[1, 2, 3, 4], reshape_hidden_states=False)
    config = DepthAnythingConfig(backbone_config=backbone, reassemble_hidden_size=16, neck_hidden_sizes=[8, 8, 16, 16],
                                 fusion_hidden_size=8, head_hidden_size=4)
    model = DepthAnythingForDepthEstimation(config).eval()
    with torch.no_grad():  # a positive output, so that alignment has something to fit
        model.head.conv3.bias.fill_(1.0)
    model.save_pretrained(path)
    DPTImageProcessorPil(do_resize=True, size={"height": 56, "width": 56}, keep_aspect_ratio=True,
                         ensure_multiple_of=14, do_pad=False, resample=3,
                         image_mean=[0.485, 0.456, 0.406], image_std=[0.229, 0.224, 0.225]).save_pretrained(path)
    return path


def tiny_marigold(path):
    from diffusers import AutoencoderKL, DDIMScheduler, MarigoldIntrinsicsPipeline, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    torch.manual_seed(0)
    vae = AutoencoderKL(down_block_types=("DownEncoderBlock2D",) * 2, up_block_types=("UpDecoderBlock2D",) * 2,
                        block_out_channels=(8, 8), layers_per_block=1, latent_channels=4, norm_num_groups=4,
                        sample_size=32)
    targets = ["albedo", "shading", "residual"]  # the layout of marigold-iid-lighting
    unet = UNet2DConditionModel(sample_size=16, in_channels=4 * (1 + len(targets)), out_channels=4 * len(targets),
                                layers_per_block=1, block_out_channels=(8, 16),
                                down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
                                up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=8,
                                attention_head_dim=2, norm_num_groups=4)
    scheduler = DDIMScheduler(prediction_type="v_prediction", timestep_spacing="trailing", beta_schedule="scaled_linear",
                              beta_start=0.00085, beta_end=0.012, clip_sample=False, set_alpha_to_one=False)
    text = CLIPTextModel(CLIPTextConfig(hidden_size=8, intermediate_size=16, num_attention_heads=2, num_hidden_layers=1,
                                        vocab_size=100, max_position_embeddings=8, projection_dim=8,
                                        bos_token_id=0, eos_token_id=1, pad_token_id=1))
    tok_dir = path.parent / "tok"
    tok_dir.mkdir()
    (tok_dir / "vocab.json").write_text(json.dumps({"<|startoftext|>": 0, "<|endoftext|>": 1, "a</w>": 2}))
    (tok_dir / "merges.txt").write_text("#version: 0.2\n")
    tokenizer = CLIPTokenizer(vocab_file=str(tok_dir / "vocab.json"), merges_file=str(tok_dir / "merges.txt"),
                              model_max_length=8)
    props = {"target_names": targets, "albedo": {"prediction_space": "linear"},
             "shading": {"prediction_space": "linear"}, "residual": {"prediction_space": "linear"}}
    MarigoldIntrinsicsPipeline(unet=unet, vae=vae, scheduler=scheduler, text_encoder=text, tokenizer=tokenizer,
                               prediction_type="intrinsics", target_properties=props, default_denoising_steps=2,
                               default_processing_resolution=32).save_pretrained(path)
    return path
