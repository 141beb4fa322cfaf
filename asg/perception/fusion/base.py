"""The V2X detector interface: a cooperative frame in, boxes in the ego frame out."""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import torch

from ...registry import Registry
from ...sensors.frame import CooperativeFrame
from sumo_scenarios.paths import configs_dir

from ..config import DEFAULT_CONFIG_FILE, DetectorConfig, load_detector_config
from ..data import in_range
from ..feeds import AGENT_CLOUDS, Feed
from ..inference import fold_batch_norms, relus_in_place
from ..model import postprocess
from ..point_stage import PointStage, refine


def load_point_stage(weights_name: str, weights_file: str | None) -> PointStage | None:
    """The point stage of a detector whose weights are ``weights_name`` (or ``weights_file``), loaded
    (asg.perception.weights_io.stage_file_for says which); None when none is shipped."""
    from ..weights_io import load_state, stage_file_for

    path = stage_file_for(weights_name, weights_file)
    return None if path is None else relus_in_place(load_state(PointStage(), path))

Detections = tuple[np.ndarray, np.ndarray]  # boxes (K, 7) in the ego sensor frame, scores (K,)


class V2XDetector(ABC):
    """A fusion method around trained weights. ``detect`` never trains and never mutates the frame."""

    registry_name: str = ""
    #: the shipped weights file under asg/perception/weights/
    weights: str = ""
    #: its network's settings: a file of configs/detectors/ (a larger or slimmer variant of a model
    #: is its own entry with its own file and weights)
    config_file: str = DEFAULT_CONFIG_FILE
    #: how training feeds the network (asg.perception.feeds): the examples of a frame, and how a
    #: batch of them enters the network; None for a detector asg does not train (a plugin)
    feed: "Feed | None" = None
    #: the shipped model whose network and weights these weights fine-tune ("" for a model trained
    #: by ``asg train``, with its block in train.yaml)
    fine_tuned_from: str = ""
    #: does it bring the attention weights ACS-A reads (``attention_weights`` returns them)?
    has_attention: bool = False

    def __init__(self, cfg: DetectorConfig | None = None, weights_file: str | None = None, load: bool = True):
        self.cfg = cfg or self.detector_config()
        self.model = self.build_model()
        self.point_stage = None
        if load:
            from ..weights_io import load_state, weights_path

            load_state(self.model, weights_file or weights_path(self.weights))
            if self.cfg.point_stage:
                self.point_stage = load_point_stage(self.weights, weights_file)
        self.model.eval()
        fold_batch_norms(self.model)
        # the canvases are channels-last (see PillarEncoder); weights in the same layout spare
        # oneDNN a reorder per convolution
        self.model.to(memory_format=torch.channels_last)

    @classmethod
    def new_network(cls, cfg: DetectorConfig) -> torch.nn.Module:
        """A fresh, trainable network of this model (what its weights load into and training builds)."""
        raise NotImplementedError(f"{cls.__name__} defines no network")

    @classmethod
    def detector_config(cls) -> DetectorConfig:
        """The settings its network is built with (configs/detectors/``config_file``)."""
        return load_detector_config(configs_dir() / "detectors" / cls.config_file)

    @classmethod
    def card_settings(cls, cfg: DetectorConfig) -> dict:
        """Settings of ``cfg`` particular to this model, recorded in its weights' model card."""
        return {}

    def build_model(self) -> torch.nn.Module:
        return self.new_network(self.cfg)

    @abstractmethod
    def detect(self, frame: CooperativeFrame) -> Detections:
        """Boxes (K, 7) and scores (K,) in the ego sensor frame, within the evaluation range."""

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float] | None:
        """Ego-row attention toward each agent, averaged over BEV cells; None for non-attention models."""
        return None

    def refined(self, boxes: np.ndarray, scores: np.ndarray, cloud: np.ndarray) -> Detections:
        """Boxes (K, 7) and scores (K,) after the point stage, from ``cloud`` (N, 4), all in the
        detecting frame; as they are when the stage is off or none is shipped."""
        if self.point_stage is None:
            return boxes, scores
        return refine(self.point_stage, boxes, scores, cloud, self.cfg.point_stage_rescore)

    def seen_cloud(self, frame: CooperativeFrame) -> np.ndarray:
        """(N, 4) the points behind this detector's boxes, in the ego frame: every sensing agent's
        (the fusion models, and Late Fusion's boxes from every agent); No Fusion's: the ego's own."""
        return np.vstack(frame.clouds_in_frame_of(frame.ego_id))

    @staticmethod
    def _clip(boxes: np.ndarray, scores: np.ndarray) -> Detections:
        keep = in_range(boxes)
        return boxes[keep], scores[keep]


class AgentCloudsDetector(V2XDetector):
    """A detector whose network takes every sensing agent's cloud moved to the ego frame, apart
    (AttFuse, F-Cooper): trained with the agent-clouds feed, detecting in one pass."""

    feed = AGENT_CLOUDS

    def _clouds(self, frame: CooperativeFrame) -> list[torch.Tensor]:
        return [torch.from_numpy(c) for c in frame.clouds_in_frame_of(frame.ego_id)]

    def _sample(self, frame: CooperativeFrame, clouds: list[torch.Tensor]):
        """The frame as the network takes one sample, made by the detector's feed as in training."""
        return self.feed.network_input([clouds], [frame.kinds_in_frame_of(frame.ego_id)],
                                       [frame.delays_in_frame_of(frame.ego_id)])[0]

    @torch.no_grad()
    def detect(self, frame: CooperativeFrame) -> Detections:
        clouds = self._clouds(frame)
        boxes, scores = postprocess(self.model([self._sample(frame, clouds)]), self.model, self.cfg)[0]
        return self._clip(*self.refined(boxes, scores, torch.cat(clouds).numpy()))


#: the shipped detectors (``--fusion``): one module of this package each, filled by its import;
#: each entry (a V2XDetector class) knows its weights, network, feed and capabilities
FUSIONS: "Registry[type[V2XDetector]]" = Registry("fusion", "--fusion")
