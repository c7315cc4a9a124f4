"""The real-photo index: the fixed held-out split and the facade masks read from both label formats."""

from __future__ import annotations

import numpy as np

from companion.depth.training.realdata import facade_mask, list_real_photos, load_image, split_of
from evaluation.shared_data import shared_data_root


def test_split_is_fixed_by_name_and_holds_out_test_only_sets():
    photos = list_real_photos(shared_data_root())
    train = [p for p in photos if p.split == "train"]
    heldout = [p for p in photos if p.split == "heldout"]
    assert len(photos) == len(train) + len(heldout) > 800
    # about a fifth of the labelled photos are held out, and the unlabelled test sets never reach training
    labelled = [p for p in photos if p.label is not None]
    share = sum(p.split == "heldout" for p in labelled) / len(labelled)
    assert 0.12 < share < 0.28
    assert all(p.split == "heldout" for p in photos if p.source in ("strecha", "dji"))
    # the split depends on the name only, not on the folder it is read from
    assert split_of(train[0].image) == split_of(train[0].image.with_name(train[0].image.name))
    assert {p.image for p in list_real_photos(shared_data_root(), split="train")} == {p.image for p in train}


def test_cmp_mask_keeps_windows_and_drops_background():
    cmp = [p for p in list_real_photos(shared_data_root()) if p.source == "cmp"]
    photo = cmp[0]
    mask = facade_mask(photo)
    image = load_image(photo)
    assert mask.shape == image.shape[:2] and mask.dtype == np.uint8
    from PIL import Image

    index = np.array(Image.open(photo.label))
    assert np.all(mask[index == 3] == 255)  # windows are facade
    assert np.all(mask[index == 1] == 0)  # class 1 = background


def test_labelme_background_photos_are_mostly_background():
    backgrounds = [p for p in list_real_photos(shared_data_root()) if p.source == "labelmefacade-bg"][:5]
    shares = [float((facade_mask(p) > 0).mean()) for p in backgrounds]
    assert all(s < 0.7 for s in shares), shares
