import math

import numpy as np
import pytest

from asg.metrics import average_precision, bev_iou_matrix
from asg.objective import ObjectiveConfig, adversarial_loss

CAR = np.array([0.0, 0.0, 0.75, 4.0, 2.0, 1.5, 0.0])


def box(x=0.0, y=0.0, yaw=0.0, l=4.0, w=2.0):
    return np.array([x, y, 0.75, l, w, 1.5, yaw])


def test_iou_identical_disjoint_symmetric():
    a = np.stack([box(), box(10, 0), box(1.0, 0.5, 0.3)])
    m = bev_iou_matrix(a, a)
    assert np.allclose(np.diag(m), 1.0)
    assert m[0, 1] == 0.0
    assert np.allclose(m, m.T)
    # half-overlap along x: intersection 2 x 2 = 4, union 12
    assert bev_iou_matrix(box()[None], box(2.0)[None])[0, 0] == pytest.approx(4 / 12)
    # a 90-degree turn of a 4 x 2 box: intersection 2 x 2 = 4, union 8 + 8 - 4 = 12
    assert bev_iou_matrix(box()[None], box(yaw=math.pi / 2)[None])[0, 0] == pytest.approx(4 / 12)


def test_footprints_match_the_agent_outline():
    from asg.objective.iou import bev_footprints
    from asg.scene import footprint_xy

    rng = np.random.default_rng(3)
    boxes = np.column_stack([rng.uniform(-9, 9, (12, 2)), np.zeros(12), rng.uniform(3, 12, 12), rng.uniform(1.5, 3, 12),
                             np.full(12, 1.5), rng.uniform(-np.pi, np.pi, 12)])
    expected = np.stack([footprint_xy(b[0], b[1], b[6], b[3], b[4]) for b in boxes])
    assert np.allclose(bev_footprints(boxes), expected)


def test_rectangle_overlap_agrees_with_shapely():
    """The numpy clipping against GEOS's overlay: random pairs (crossing, nested, apart), the same
    box twice, boxes sharing an edge or a corner, a box turned by 90 and 180 degrees."""
    import shapely

    from asg.objective.iou import bev_footprints, rectangle_overlap_m2

    rng = np.random.default_rng(7)
    n = 3000
    a = np.column_stack([rng.uniform(-3, 3, (n, 2)), np.zeros(n), rng.uniform(0.5, 8, n), rng.uniform(0.5, 3, n),
                         np.ones(n), rng.uniform(-np.pi, np.pi, n)])
    b = np.column_stack([rng.uniform(-3, 3, (n, 2)), np.zeros(n), rng.uniform(0.5, 8, n), rng.uniform(0.5, 3, n),
                         np.ones(n), rng.uniform(-np.pi, np.pi, n)])
    special_a = np.stack([box(), box(), box(), box(), box(), box(1, 1, 0.3)])
    special_b = np.stack([box(), box(4.0), box(4.0, 2.0), box(yaw=math.pi / 2), box(yaw=math.pi), box(1, 1, 0.3, 1.0, 0.5)])
    a, b = np.vstack([a, special_a]), np.vstack([b, special_b])
    fa, fb = bev_footprints(a), bev_footprints(b)
    expected = shapely.area(shapely.intersection(shapely.polygons(fa), shapely.polygons(fb)))
    got = rectangle_overlap_m2(fa, fb)
    assert np.allclose(got, expected, rtol=0, atol=1e-9)
    assert (expected > 0).sum() > n // 3 and (expected == 0).sum() > n // 10  # both kinds of pair were tried
    assert got[-6] == pytest.approx(8.0) and got[-5] == 0.0 and got[-4] == 0.0 and got[-1] == pytest.approx(0.5)


def test_ap_perfect():
    gt = np.stack([box(), box(10, 0)])
    assert average_precision([(gt, np.array([0.9, 0.8]), gt)], 0.7) == pytest.approx(1.0)


def test_ap_empty_predictions_and_no_ground_truth():
    gt = np.stack([box()])
    assert average_precision([(np.zeros((0, 7)), np.zeros(0), gt)], 0.5) == 0.0
    assert average_precision([(gt, np.array([0.9]), np.zeros((0, 7)))], 0.5) == 0.0


def test_ap_shifted_box_passes_low_threshold_only():
    gt = box()[None]
    pred = box(1.0)[None]  # IoU = 6 / 10 = 0.6
    frames = [(pred, np.array([0.9]), gt)]
    assert average_precision(frames, 0.5) == pytest.approx(1.0)
    assert average_precision(frames, 0.7) == 0.0


def test_ap_duplicates_are_false_positives():
    gt = box()[None]
    pred = np.stack([box(), box(0.05)])
    # one TP at score 0.9 then an FP: precision envelope 1.0 up to recall 1 -> AP 1.0
    assert average_precision([(pred, np.array([0.9, 0.8]), gt)], 0.5) == pytest.approx(1.0)
    # the duplicate scoring higher than the true match: first the better IoU box is matched... order matters
    pred2 = np.stack([box(3.0), box()])
    ap = average_precision([(pred2, np.array([0.95, 0.9]), gt)], 0.5)
    assert ap == pytest.approx(0.5)  # FP first (IoU 1/7), then TP: precision 1/2 at recall 1


def test_ap_sorts_detections_globally_across_frames():
    gt = box()[None]
    # frame 1: a confident false positive; frame 2: a weak true positive
    f1 = (box(20.0)[None], np.array([0.9]), gt)
    f2 = (box()[None], np.array([0.3]), gt)
    # global order: FP(0.9), TP(0.3): recall 0.5 at precision 0.5 -> AP = 0.25
    assert average_precision([f1, f2], 0.5) == pytest.approx(0.25)
    assert average_precision([f2, f1], 0.5) == pytest.approx(0.25)


def test_weighted_loss():
    assert adversarial_loss({"0.3": 1.0, "0.5": 1.0, "0.7": 1.0}) == pytest.approx(2.3)
    cfg = ObjectiveConfig(weights={"0.5": 2.0})
    assert adversarial_loss({"0.3": 0.1, "0.5": 0.25, "0.7": 0.0}, cfg) == pytest.approx(0.5)


def test_per_frame_ap_keeps_each_frames_order_hand_computed():
    """The paper's yardstick (OpenCOOD's evaluation without the global sort) on a case computed by hand."""
    from asg.objective.ap import ap_at, ap_by_method

    gt = box()[None]
    # frame 1: a true positive at 0.9 and a false positive at 0.1; frame 2: a true positive at 0.8
    f1 = (np.stack([box(), box(20.0)]), np.array([0.9, 0.1]), gt)
    f2 = (box()[None], np.array([0.8]), gt)
    # global: TP .9, TP .8, FP .1 -> precision 1 up to recall 1: AP 1
    assert average_precision([f1, f2], 0.5, "global") == pytest.approx(1.0)
    # per frame: TP, FP (frame 1), then TP (frame 2) -> precision 1 at recall 1/2, 2/3 at recall 1
    assert average_precision([f1, f2], 0.5, "per-frame") == pytest.approx(0.5 + 0.5 * 2 / 3)
    # per frame depends on the frames' order: frame 2 first gives TP, TP, FP -> AP 1
    assert average_precision([f2, f1], 0.5, "per-frame") == pytest.approx(1.0)
    # within a frame the detections are still ranked by score, whatever order they are given in
    f1_reversed = (f1[0][::-1].copy(), f1[1][::-1].copy(), gt)
    assert average_precision([f1_reversed, f2], 0.5, "per-frame") == pytest.approx(0.5 + 0.5 * 2 / 3)
    both = ap_by_method([f1, f2])
    assert both["global"] == ap_at([f1, f2]) and both["per-frame"] == ap_at([f1, f2], method="per-frame")
    for method in ("global", "per-frame"):  # every threshold of one call as average_precision's own
        shifted = [(f[0] + (0.8, 0.3, 0, 0, 0, 0, 0.2), f[1], f[2]) for f in (f1, f2)]
        assert ap_at(shifted, (0.1, 0.3, 0.5, 0.7), method) == {
            f"{t:g}": average_precision(shifted, t, method) for t in (0.1, 0.3, 0.5, 0.7)}
        assert len(set(ap_at(shifted, (0.1, 0.3, 0.5, 0.7), method).values())) > 1


def test_per_frame_ap_equals_opencoods_unsorted_evaluation():
    """Random frames scored as OpenCOOD's eval_utils did without --global_sort_detections (rewritten
    here: tp/fp lists per frame in score order, concatenated, cumulative sums, VOC envelope)."""
    from asg.objective.ap import match_frame, voc_ap

    rng = np.random.default_rng(3)
    frames = []
    for _ in range(12):
        m, n = rng.integers(0, 5), rng.integers(0, 7)
        gt = np.array([box(float(x)) for x in rng.uniform(-30, 30, m)]).reshape(-1, 7)
        pred = np.array([box(float(x)) for x in rng.uniform(-30, 30, n)]).reshape(-1, 7)
        if m and n:
            pred[: min(m, n)] = gt[: min(m, n)] + rng.normal(0, 0.3, (min(m, n), 7)) * [1, 1, 0, 0, 0, 0, 0.2]
        frames.append((pred, rng.uniform(0.2, 1.0, n), gt))
    for t in (0.3, 0.5, 0.7):
        tp_list, fp_list, n_gt = [], [], 0
        for pred, scores, gt in frames:
            order = np.argsort(-scores)
            tp = match_frame(pred, scores, gt, t)[order]
            tp_list += tp.astype(int).tolist()
            fp_list += (~tp).astype(int).tolist()
            n_gt += len(gt)
        ctp, cfp = np.cumsum(tp_list), np.cumsum(fp_list)
        want = voc_ap(ctp / n_gt, ctp / (ctp + cfp))
        assert average_precision(frames, t, "per-frame") == pytest.approx(want)


def test_an_unknown_ap_method_is_one_line():
    from sumo_scenarios.errors import InputError

    with pytest.raises(InputError, match="per-frame"):
        average_precision([], 0.5, "sorted")


def test_a_pooled_ap_reads_every_form_a_card_has_held():
    """Today's form ({"ap", "ap_per_frame"}) round-trips; cards written before it (AP by threshold at
    the top, the paper's under "per_frame"; a data set's index with "ap_normal") read the same."""
    from asg.objective.pooled import REATTACK_PAIR, PooledAP, pair_json, pooled_pair

    ours, paper = {"0.3": 0.9, "0.5": 0.8, "0.7": 0.7}, {"0.3": 0.8, "0.5": 0.7, "0.7": 0.6}
    pooled = PooledAP(ours, paper)
    assert PooledAP.from_json(pooled.to_json()) == pooled
    assert pooled.of("global") == ours and pooled.of("per-frame") == paper and pooled.text() == "70.0 / 60.0"
    assert PooledAP.from_json(ours | {"frames": 3, "per_frame": paper}) == pooled
    assert PooledAP.from_json(ours) == PooledAP(ours, None) and PooledAP(ours).text() == "70.0 / -"
    new = {"frames": 3, **pair_json({"normal": pooled, "challenging": PooledAP(paper, ours)})}
    old_card = {"frames": 3, "normal": ours, "challenging": paper, "per_frame": {"normal": paper, "challenging": ours}}
    old_index = {"ap_normal": ours, "ap_challenging": paper, "per_frame": {"ap_normal": paper, "ap_challenging": ours}}
    assert pooled_pair(new, REATTACK_PAIR) == pooled_pair(old_card, REATTACK_PAIR) == pooled_pair(old_index, REATTACK_PAIR)
    assert pooled_pair({"normal": ours, "challenging": paper}, REATTACK_PAIR)["normal"].ap_per_frame is None


def test_a_summary_aggregate_reads_under_one_key_per_stage_and_in_its_older_form():
    """A stage's pooled AP sits under the same key as a scene's AP ("ap_final" for the final stage);
    summaries written before that ("ap_challenging") read the same, under both yardsticks."""
    from asg.generator.run_folder import aggregate_ap, aggregate_pooled
    from asg.generator.stages import Stage
    from asg.objective.pooled import PooledAP

    ours, paper = {"0.3": 0.9, "0.5": 0.8, "0.7": 0.7}, {"0.3": 0.8, "0.5": 0.7, "0.7": 0.6}
    assert [s.ap_key for s in Stage] == ["ap_normal", "ap_after_acs", "ap_final"]
    new = {"ap_normal": ours, "ap_final": paper, "by_method": {"global": {"ap_normal": ours, "ap_final": paper},
                                                               "per-frame": {"ap_normal": paper, "ap_final": ours}}}
    old = {"ap_normal": ours, "ap_challenging": paper,
           "by_method": {"global": {"ap_normal": ours, "ap_challenging": paper},
                         "per-frame": {"ap_normal": paper, "ap_challenging": ours}}}
    for agg in (new, old):
        assert aggregate_pooled(agg, Stage.FINAL) == PooledAP(paper, ours)
        assert aggregate_ap(agg, Stage.NORMAL, "per-frame") == paper and aggregate_ap(agg, Stage.AFTER_ACS) is None


def test_the_iou_of_boxes_with_themselves_is_their_iou_with_a_copy():
    """bev_iou_matrix(a) (each pair once, the diagonal set) equals bev_iou_matrix(a, a), a box of
    no area included (0 with itself, as clipping gives)."""
    a = np.stack([box(), box(1.0, 0.5, 0.3), box(0.5, 0.2, 1.0, l=0.0), box(20, 0), box(2.0)])
    assert np.allclose(bev_iou_matrix(a), bev_iou_matrix(a, a), rtol=0, atol=1e-12)
    assert bev_iou_matrix(a)[2, 2] == 0.0 and bev_iou_matrix(a)[0, 0] == 1.0
