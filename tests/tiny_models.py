"""Tiny randomly initialised OWLv2 and CLIP checkpoints saved to a local folder (no download):
the real adapters load them exactly as they load real weights."""

from __future__ import annotations

import string
from pathlib import Path


def save_tiny_models(root: Path) -> tuple[Path, Path]:
    """(owlv2 folder, clip folder) under ``root``, in ``save_pretrained`` layout."""
    import torch
    import transformers

    torch.manual_seed(0)
    vocab = {"!": 0, "<|endoftext|>": 1, "<|startoftext|>": 2}
    for ch in list(string.ascii_lowercase) + list(string.digits) + ["(", ")", ".", "'", "-"]:
        vocab.setdefault(ch, len(vocab))
        vocab.setdefault(ch + "</w>", len(vocab))
    tok = transformers.CLIPTokenizer(vocab=vocab, merges=[])
    text = dict(vocab_size=len(vocab), hidden_size=32, intermediate_size=37, num_hidden_layers=1, num_attention_heads=2,
                max_position_embeddings=16, bos_token_id=2, eos_token_id=1, pad_token_id=1)
    vision = dict(hidden_size=32, intermediate_size=37, num_hidden_layers=1, num_attention_heads=2, image_size=32,
                  patch_size=8)
    owl_dir, clip_dir = Path(root) / "owlv2", Path(root) / "clip"
    owl = transformers.Owlv2ForObjectDetection(transformers.Owlv2Config(text_config=text, vision_config=vision,
                                                                        projection_dim=32))
    owl.save_pretrained(owl_dir)
    transformers.Owlv2Processor(image_processor=transformers.Owlv2ImageProcessor(size={"height": 32, "width": 32}),
                                tokenizer=tok).save_pretrained(owl_dir)
    clip = transformers.CLIPModel(transformers.CLIPConfig(text_config=text, vision_config=vision, projection_dim=16))
    clip.save_pretrained(clip_dir)
    transformers.CLIPProcessor(image_processor=transformers.CLIPImageProcessor(size={"shortest_edge": 32},
                                                                               crop_size={"height": 32, "width": 32}),
                               tokenizer=tok).save_pretrained(clip_dir)
    return owl_dir, clip_dir
