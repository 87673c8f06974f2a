"""Grad-CAM of a regressor's network: where in the image its estimate comes from (``gradcam.png`` of
``hybridpose eval``)."""
from __future__ import annotations

import numpy as np
import torch

from ..core import Frame
from ..io import write_image
from ..regressors.predictor import CheckpointRegressor


def gradcam(reg: CheckpointRegressor, frame: Frame) -> np.ndarray:
    """(H, W) float in [0, 1]: Grad-CAM of the network's deepest feature map for ``frame``.

    The score differentiated is the sum of each keypoint heatmap's peak logit (keypoint models)
    or the sum of the pose outputs (direct models); the map is shown on the network's input. For the
    parallel model it is its rotation stream's, on the bounded image it crops at inference (the sheet
    ranks views by rotation error; its translation stream sees the whole frame).
    """
    import cv2

    from ..geometry.crops import crop_box, crop_image
    from ..regressors.detection import CROP_MARGIN, detect_bright_object

    net = reg.net
    # direct models: the last module of the VGG features (its final max-pool), not the features
    # Sequential itself — the branched model runs slices of it, which a hook on the whole never sees
    parallel = reg.model_name == "parallel-vgg19"
    layer = net.layer4 if reg.kind == "keypoints" else (net.rotation.features if parallel else net.features)[-1]
    feats = {}
    h1 = layer.register_forward_hook(lambda m, i, o: feats.__setitem__("a", o))
    h2 = layer.register_full_backward_hook(lambda m, gi, go: feats.__setitem__("g", go[0]))
    try:
        S = reg.image_size
        if reg.kind == "keypoints":
            box = detect_bright_object(frame.image)
            box = crop_box(box, CROP_MARGIN) if box else ((frame.camera.width - 1) / 2, (frame.camera.height - 1) / 2, float(frame.camera.width))
            img, _ = crop_image(frame.image, frame.camera.K, *box, (S, S))
        elif parallel:  # the crop predict gives the rotation stream without a roi
            with torch.no_grad():
                img = reg.bounded_image(frame)
        else:
            img = cv2.resize(frame.image, (S, S), interpolation=cv2.INTER_AREA)
        x = reg.tensor(img).requires_grad_(True)
        with torch.enable_grad():
            if reg.kind == "keypoints":
                score = net.heatmaps(x).flatten(2).max(-1).values.sum()
            elif parallel:
                score = net.rotation(x).sum()
            else:
                t, q = net(x)
                score = t.sum() + q.sum()
            net.zero_grad()
            score.backward()
        a, g = feats["a"][0], feats["g"][0]
        cam = torch.relu((g.mean((1, 2), keepdim=True) * a).sum(0)).detach().float().cpu().numpy()
    finally:
        h1.remove()
        h2.remove()
    cam = cv2.resize(cam, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_LINEAR)
    cam = cam / cam.max() if cam.max() > 0 else cam
    return img, cam


def write_gradcam_sheet(reg, items, labels, path) -> None:
    import cv2

    from ..viz import contact_sheet

    tiles = []
    for scene, im_id in items:
        frame = Frame(scene.rgb(im_id), scene.image(im_id).camera, 0.0)
        img, cam = gradcam(reg, frame)
        heat = cv2.applyColorMap((255 * cam).astype(np.uint8), cv2.COLORMAP_JET)[:, :, ::-1]
        tiles.append((0.55 * img + 0.45 * heat).astype(np.uint8))
    write_image(path, contact_sheet(tiles, columns=max(1, len(tiles) // 2), tile_width=192, labels=labels))
