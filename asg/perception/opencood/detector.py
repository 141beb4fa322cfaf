"""An OpenCOOD model as a target: a cooperative frame in, boxes in the ego's sensor frame out, every
step between them OpenCOOD's own code (its dataset's processing, model forward and post-processor),
AttFuse's fusion computed by the ego's row of its attention (asg/perception/opencood/attention.py:
OpenCOOD's function, several times faster on CPU) and its pillar net's batch norm and max over points
taken in the other order (asg/perception/opencood/pillar_max.py: the same bits)."""
from __future__ import annotations

import shutil
import tempfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

from sumo_scenarios.errors import InputError

from ...sensors.opv2v import agent_views, frame_ids
from ...sensors.frame import CooperativeFrame
from ..data import in_range
from .attention import ego_row_weights, use_ego_row
from .folder import FUSION_KINDS, MODELS, checkpoint_of, load_checkpoint, read_hypes
from .pillar_max import use_pillar_max
from .runtime import module

#: OpenCOOD shuffles each agent's cloud with numpy's global generator before voxelising (which points
#: a full pillar keeps): the adapter seeds it with this for every frame, restoring the caller's state
FRAME_SEED = 0


class OpenCOODDetector:
    """OpenCOOD's model of ``folder`` behind asg's detector interface (``detect``, ``attention_weights``)."""

    #: nothing of asg trains it (OpenCOOD's own trainer does); no asg weights, feed or point stage
    weights = ""
    feed = None
    fine_tuned_from = ""
    point_stage = None

    def __init__(self, folder: Path, name: str):
        self.registry_name = name
        self.folder = folder
        hypes = read_hypes(folder)
        self.kind = FUSION_KINDS[hypes["fusion"]["core_method"]]
        self.has_attention = MODELS[hypes["model"]["core_method"]] and self.kind == "intermediate"
        empty = tempfile.mkdtemp(prefix="asg-opencood-")  # its dataset lists a data folder: an empty one
        step = "dataset"
        try:
            self.dataset = module("data_utils.datasets").build_dataset(
                {**hypes, "root_dir": empty, "validate_dir": empty}, visualize=False, train=False)
            step = "model"
            self.model = module("tools.train_utils").create_model(hypes)
        except (Exception, SystemExit) as exc:  # the last wall: whatever OpenCOOD raises (it calls sys.exit too)
            raise InputError(f"{folder}: OpenCOOD could not build its {step} ({_first_line(exc)}); check the "
                             "folder's config.yaml against OpenCOOD's hypes_yaml") from None
        finally:
            shutil.rmtree(empty, ignore_errors=True)
        load_checkpoint(self.model, checkpoint_of(folder))
        self.model.eval()
        self.fusions = use_ego_row(self.model)  # AttFuse's attention by the ego's row: OpenCOOD's function, faster
        use_pillar_max(self.model)  # its pillar net's max before its batch norm: the same bits, faster
        self.infer = getattr(module("tools.inference_utils"), f"inference_{self.kind}_fusion")
        self._corner_to_center = module("utils.box_utils").corner_to_center

    def base_data(self, frame: CooperativeFrame, labelled: bool = False) -> tuple[OrderedDict, float]:
        """The frame as OpenCOOD's ``retrieve_base_data`` returns it from the OPV2V export (ego first,
        the others in its folder order; ``labelled``: with the frame's ground truth listed, as the
        export lists the scene's vehicles), and how far the ego's frame is lowered (m)."""
        ids = frame_ids(frame, every_vehicle=labelled)
        views, drops = agent_views(frame, ids, labelled=labelled)
        order = [frame.ego_id] + sorted((a for a in frame.sensing_ids if a != frame.ego_id), key=lambda a: str(ids[a]))
        data = OrderedDict()
        for a in order:
            meta, cloud = views[a]
            data[str(ids[a])] = OrderedDict(ego=a == frame.ego_id, params=meta, lidar_np=cloud)
        return data, drops[frame.ego_id]

    def _run(self, frame: CooperativeFrame, with_truth: bool = False):
        """(corners (K, 8, 3) or None, scores (K,) or None) in OpenCOOD's ego frame, the base data it ran
        on (:meth:`base_data`) and the ego frame's drop (m); ``with_truth``: OpenCOOD's own ground
        truth corners (M, 8, 3) of the frame too, last."""
        import torch

        data, lowered_m = self.base_data(frame, labelled=with_truth)
        self.dataset.retrieve_base_data = lambda idx: data
        state = np.random.get_state()
        np.random.seed(FRAME_SEED)
        step = "pre-processing"
        try:
            batch = self.dataset.collate_batch_test([self.dataset[0]])
            step = "model and post-processing"
            with torch.no_grad():
                corners, scores, truth = self.infer(batch, self.model, self.dataset)
        except (Exception, SystemExit) as exc:  # the last wall: whatever OpenCOOD raises (it calls sys.exit too)
            raise InputError(f"{self.folder}: OpenCOOD's {step} failed on {frame.scene_id} "
                             f"({_first_line(exc)}); check the folder's config.yaml") from None
        finally:
            np.random.set_state(state)
        return (corners, scores, data, lowered_m, truth) if with_truth else (corners, scores, data, lowered_m)

    def detect(self, frame: CooperativeFrame) -> tuple[np.ndarray, np.ndarray]:
        """Boxes (K, 7) x, y, z (centre), l, w, h, yaw in the ego's sensor frame and scores (K,),
        within the evaluation range."""
        corners, scores, _, lowered_m = self._run(frame)
        boxes, scores = self._boxes(corners, lowered_m), _numpy(scores)
        keep = in_range(boxes)
        return boxes[keep], scores[keep]

    def opencood_frame(self, frame: CooperativeFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(boxes (K, 7), scores (K,), ground truth (M, 7)) as OpenCOOD's own ``tools/inference.py``
        scores the frame, in the ego's sensor frame: its detections as its post-processor leaves them
        (no cut to asg's evaluation range) and its test-time ground truth (every vehicle any agent
        lists, the ego's own car where a collaborator lists it, kept where all eight corners lie in
        its fixed range, GT_RANGE: |x| <= 140 m, |y| <= 40 m, -3 <= z <= 1 m in its ego frame)."""
        corners, scores, _, lowered_m, truth = self._run(frame, with_truth=True)
        return self._boxes(corners, lowered_m), _numpy(scores), self._boxes(truth, lowered_m)

    def _boxes(self, corners, lowered_m: float) -> np.ndarray:
        """Corners (K, 8, 3) of OpenCOOD's ego frame (a tensor, or None) as boxes (K, 7) in asg's."""
        if corners is None or len(corners) == 0:
            return np.zeros((0, 7))
        boxes = self._corner_to_center(corners.detach().cpu().numpy().astype(np.float64), order="lwh")
        return boxes_from_opv2v(boxes, lowered_m)

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float] | None:
        """AttFuse's ego-row self-attention toward each agent, averaged over BEV cells and over the
        backbone's fusion stages (an agent beyond OpenCOOD's communication range: 0); None for a
        model without attention."""
        if not self.has_attention:
            return None
        rows = []

        def keep(fusion, args):
            x, record_len = args  # (agents, C, H, W) of the one scene, the ego first
            rows.append(ego_row_weights(x[:int(record_len[0])], fusion.att.sqrt_dim).mean(dim=(1, 2)).numpy())

        hooks = [m.register_forward_pre_hook(keep) for m in self.fusions]
        try:
            _, _, data, _ = self._run(frame)
        finally:
            for h in hooks:
                h.remove()
        kept = self._agents_in_range(frame, data)
        weights = np.mean([r for r in rows if len(r) == len(kept)], axis=0) if rows else np.ones(len(kept)) / len(kept)
        out = {a: 0.0 for a in frame.sensing_ids}
        out.update({a: float(w) for a, w in zip(kept, weights)})
        return out

    @staticmethod
    def _agents_in_range(frame: CooperativeFrame, data: OrderedDict) -> list[str]:
        """Our ids of the agents OpenCOOD's intermediate dataset keeps (within its COM_RANGE of the
        ego's LiDAR), in its order."""
        com_range_m = module("data_utils.datasets").COM_RANGE
        by_id = {str(i): a for a, i in frame_ids(frame).items()}
        ego = next(iter(data.values()))["params"]["lidar_pose"]
        return [by_id[k] for k, v in data.items()
                if np.hypot(v["params"]["lidar_pose"][0] - ego[0], v["params"]["lidar_pose"][1] - ego[1]) <= com_range_m]


def _numpy(scores) -> np.ndarray:
    return np.zeros(0) if scores is None else scores.detach().cpu().numpy().astype(np.float64).reshape(-1)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:160]}" if text else type(exc).__name__


def boxes_from_opv2v(boxes: np.ndarray, lowered_m: float) -> np.ndarray:
    """(K, 7) boxes of OpenCOOD's ego frame (the export's: y mirrored, the ego's frame lowered by
    ``lowered_m``) in asg's ego sensor frame: y and yaw back, z back down."""
    out = np.array(boxes, dtype=np.float64)
    out[:, 1] = -out[:, 1]
    out[:, 2] -= lowered_m
    out[:, 6] = -out[:, 6]
    return out
