"""Typed settings for every stage. Defaults are the source papers' values.

Fisheye paper = 'Pipe Mapping with Monocular Fisheye Imagery' (sections III-A..E, IV-B);
2010 report = 'Towards a Visual Perception System for Pipe Inspection' (sections 3-6).
Settings load from YAML and take `section.key=value` overrides from the command line;
every run records the settings it used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipemap.errors import PipemapError
from pipemap.yamlfile import read_yaml


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class FrontendSettings(_Section):
    """Fisheye feature tracking (fisheye paper III-A)."""

    tracking: Literal["flow", "descriptors"] = Field(
        "flow", description="how a frame is followed from the last keyframe: flow (pyramidal Lucas-Kanade from frame "
        "to frame, corners, RANSAC and the anchor match only where a keyframe is made: frontend/flow_tracker.py) or "
        "descriptors (corners described and matched in every frame, guided ZNCC at keyframes: frontend/tracker.py)")
    flow_window_px: int = Field(15, ge=5, description="Lucas-Kanade window between frames (px, odd), at the "
                                "reference density: a finer camera's frames are followed at that density, halved "
                                "once per doubling (frontend/flow_tracker.py), so a frame costs the same at any size")
    flow_levels: int = Field(3, ge=0, description="Lucas-Kanade pyramid levels above the followed image")
    regions: tuple[int, int] = Field((2, 2), description="image split into rows x cols regions for Harris")
    corners_per_region: int = Field(200, gt=0, description="strongest Harris corners kept per region (N)")
    harris_k: float = Field(0.04, gt=0, description="Harris sensitivity")
    template_size: int = Field(11, gt=0, description="side of the grey template descriptor (px)")
    template_window: int = Field(31, gt=0, description="neighbourhood the template is interpolated from (px)")
    match_ratio: float = Field(0.9, gt=0, le=1, description="best/second-best cosine-distance ratio test")
    ransac_angle_deg: float = Field(0.2, gt=0, description="angular inlier threshold on bearings")
    ransac_confidence: float = Field(0.999, gt=0, lt=1)
    epipolar_threshold: float = Field(0.01, gt=0, description="|eta_j^T E eta_i| bound of the guided ZNCC search")
    zncc_min: float = Field(0.8, gt=-1, le=1, description="minimum ZNCC score of a guided match")
    keyframe_min_flow_px: float = Field(10.0, ge=0, description="new keyframe when median sparse flow exceeds this")
    keyframe_min_tracked: float = Field(
        0.8, ge=0, le=1, description="... or inlier matches fall below this fraction of the most any frame had since "
        "the keyframe. A camera looking along the pipe loses its near, fast tracks first, so the median flow of the "
        "rest can shrink while the camera moves on: at 0.5 the keyframe came when the new one shared 10-20 % of its "
        "tracks with scene points and the scale slipped by 10 %; at 0.7 a burst of lost tracks still left too few "
        "across one step (cctv-loop at 720x576: a side 0.9 % short); the fisheye's keyframes come by flow first")
    # What the paper leaves open: measured on renders at 640x480.
    reference_px_per_deg: float | None = Field(
        2.53, gt=0, description="pixel density (px per degree at the image centre) at which the sizes and "
        "thresholds in px of the front end and the classification are given: the fisheye paper's 190 deg camera "
        "at 640x480. A camera of another density gets them scaled by its density over this (frontend/angular.py): "
        "template footprints, ZNCC patches, search radii, flow and keyframe thresholds, the Harris scale, the "
        "lighting scale, the classification's sub-sampling; run.json lists the values used. None: px as given")
    harris_block_px: int = Field(3, ge=3, description="Harris integration window (px, odd)")
    smooth_sigma_px: float = Field(0.0, ge=0, description="Gaussian blur of every frame before corners, descriptors "
                                   "and ZNCC (px; 0: off)")
    static_mask_frames: int = Field(40, ge=0, description="frames spread over the recording in which pixels that do "
                                    "not move with the wall (burned-in text, logos, lens dirt, the robot's parts) "
                                    "are looked for and masked (frontend/static_mask.py); 0: off")
    static_mask_max_fraction: float = Field(0.3, gt=0, le=1, description="a static mask covering more of the image "
                                            "than this is not used (the robot barely moved in the frames sampled)")
    min_distance_px: int = Field(3, ge=1, description="non-maximum suppression radius of Harris corners")
    harris_quality: float = Field(0.001, ge=0, lt=1, description="corners weaker than this x the region's strongest "
                                                                 "are dropped")
    min_similarity: float = Field(0.5, ge=-1, le=1, description="smallest cosine similarity of a descriptor match")
    max_flow_px: float = Field(80.0, gt=0, description="descriptor match candidates lie within this many pixels")
    ransac_threshold_px: float = Field(0.7, gt=0, description="angular inlier threshold is at least this many pixels "
                                                              "at the centre")
    ransac_max_trials: int = Field(500, gt=0)
    rotation_check_factor: float | None = Field(1.5, gt=0, description="a relative pose whose rotation is further "
                                                "than this x its inliers' angular motion (90th percentile) plus "
                                                "rotation_check_slack_deg from the rotation that best turns them onto "
                                                "each other is refused as a wrong solution (frontend/relpose.py "
                                                "rotation_fits_motion; None: off)")
    rotation_check_slack_deg: float = Field(1.0, ge=0, description="see rotation_check_factor")
    continued_motion_share: float | None = Field(0.8, gt=0, description="where the previous relative pose, "
                                                 "refined on a keyframe's pairs, is another solution than RANSAC's "
                                                 "but keeps at least this share of its inliers, it is the pose: the "
                                                 "pairs cannot tell them apart and a crawler drives on smoothly "
                                                 "(frontend/relpose.py continued_motion; None: off)")
    continued_motion_max_inliers: int = Field(100, ge=0, description="only poses RANSAC found with at most this "
                                              "many inliers are weighed against the continued motion: with hundreds "
                                              "(640x480 H.264 CCTV: 190-380) RANSAC's pose was the right one in 6 of "
                                              "8 such ties, with a few dozen (320x240) the continued one in 13 of "
                                              "18")
    continued_motion_apart_deg: float = Field(1.0, gt=0, description="the refined previous pose is another "
                                              "solution when its rotation is this far from RANSAC's or its "
                                              "translation ten times this")
    track_threshold_factor: float = Field(2.0, gt=0, description="a match continues its track within this x the RANSAC "
                                                                 "threshold of the refined pose (the flow front end "
                                                                 "also needs RANSAC's own pose to have counted it, "
                                                                 "unless continue_on_refined_pose)")
    continue_on_refined_pose: bool = Field(False, description="flow front end: a followed feature continues its "
                                           "track wherever the pose refined on RANSAC's inliers takes it (within "
                                           "track_threshold_factor x the threshold), not only where RANSAC's own "
                                           "pose counted it: H.264 tracks live longer and the tee loop turns "
                                           "better, but clean route A's Table I and the junction networks lose "
                                           "(README)")
    min_inliers: int = Field(15, gt=5, description="fewer pose inliers means the frame is not tracked")
    zncc_patch: int = Field(11, gt=2, description="side of the raw-image ZNCC template (px)")
    guided_search_px: int = Field(8, gt=0, description="half-size of the guided ZNCC window around the predicted "
                                                       "position")
    guided_neighbours: int = Field(5, gt=0, description="matched neighbours whose median flow predicts a feature's "
                                                        "position")
    refine_matches_px: int = Field(2, ge=0, description="descriptor matches are re-located by ZNCC within this many px "
                                                        "(0: off)")
    duplicate_px: float = Field(2.0, ge=0, description="an unmatched corner this close to a guided match is dropped")
    max_lost_frames: int = Field(5, gt=0, description="after this many untracked frames, start again from a new "
                                                      "keyframe")
    flatten_lighting: bool = Field(True, description="detect, describe and correlate on log(I) minus its local mean")
    lighting_sigma_px: float = Field(4.0, gt=0, description="scale of the local mean removed with the lighting (px)")
    dark_level: float = Field(12.0, ge=0, description="no features where the local mean grey level is below this")
    contrast_limit: float = Field(16.0, ge=0, description="soft limit of the flattened image (64 x log units): "
                                  "rims of dark openings no longer outscore the wall's corners (0: off)")
    saturation_level: float | None = Field(None, ge=0, description="grey level at and above which a pixel is "
                                           "saturated: no corners within half a ZNCC patch of one, and a followed "
                                           "feature that reaches one ends (None: off). The wall close under the "
                                           "lights saturates; the edge of that region is set by the light and the "
                                           "distance, not by the wall, and drags the matches along it")
    anchor_refine: bool = Field(True, description="re-locate continued tracks against their first appearance "
                                "(affine Lucas-Kanade), so that their error does not grow with their length")
    anchor_max_shift_px: float = Field(1.5, gt=0, description="an anchor match farther than this from the ZNCC one is "
                                       "refused, and its track ends")
    anchor_min_zncc: float = Field(0.7, gt=-1, le=1, description="an anchor match correlating less than this is "
                                   "refused, and its track ends")
    anchor_iterations: int = Field(6, gt=0, description="Lucas-Kanade iterations of the anchor match")
    anchor_lighting: Literal["flattened", "plane", "quadratic"] = Field(
        "flattened", description="what the anchor match compares: flattened (the flattened image, less each patch's "
        "mean) or log brightness less a plane or a quadratic in each patch's own coordinates (the robot's light "
        "taken out the same way however much the patch is stretched: old tracks' error about a third smaller, "
        "route A's ATE 9.5 -> 6.2 mm with plane; but both turn a 30 deg sweeping bend too little, and quadratic "
        "route A's lap; README)")
    anchor_max_stretch: float = Field(2.0, gt=1, description="a track ends once its patch is stretched (or shrunk) "
                                      "more than this along any direction since it was first seen: a corner first "
                                      "seen far down the pipe, foreshortened, places its point too loosely to be "
                                      "followed when seen from close by")
    anchor_bend_neighbours: int = Field(32, ge=0, description="the anchor warp's second-order term is fitted to this "
                                        "many neighbouring matches per keyframe step (0: affine only; an affine fit "
                                        "to the bent image motion misplaces the patch centre)")
    predicted_settling_keyframes: int = Field(2, ge=0, description="on a video whose codec is in settling_codecs, "
                                              "each track's observations in this many keyframes after its first are "
                                              "left out of the map (0: none): a predicted picture copies its content "
                                              "from the pictures before, and matched against the patch cut where the "
                                              "track began it lags most just after (H.264 CRF 28: -0.074, -0.048, "
                                              "-0.034 px along the motion at the 2nd, 3rd, 4th observation; "
                                              "bench_exact_observations.py); at the default keyframe_min_flow_px, "
                                              "keyframes made further apart take proportionally fewer; only for "
                                              "a camera that sees the wall beside it (pipeline.settling_keyframes)")
    settling_codecs: list[str] = Field(["h264"], description="the video codecs (FFmpeg's names) that "
                                       "predicted_settling_keyframes applies to: measured on fisheye-straight, H.264 "
                                       "at CRF 28 went from -0.088 / -0.073 % (forward / reverse) to -0.040 / "
                                       "-0.029 %, but MPEG-4 part 2 from +0.058 / -0.094 % to +0.114 / -0.177 %")


class ClassificationSettings(_Section):
    """Straight vs T-intersection image classification (fisheye paper III-B)."""

    subsample: int = Field(2, gt=0, description="keep every n-th row and column (at frontend.reference_px_per_deg; "
                           "scaled with the camera's pixel density)")
    dark_threshold: float = Field(
        0.25, gt=0, lt=1, description="dark blobs: below this fraction of the 1st..99th percentile grey range")
    erosion_px: int = Field(2, ge=0, description="erosion radius in sub-sampled pixels")
    ratio_threshold: float = Field(1.5, gt=0, description="straight if L_p / L is below this")
    min_cluster_keyframes: int = Field(5, gt=0, description="temporal filter: minimum straight/T run, in the frames "
                                                            "classified")
    turn_deg: float | None = Field(4.0, gt=0, description="keyframes around which the viewing direction turns by "
                                   "more than this over turn_window_keyframes are a junction section too: a bend "
                                   "the images do not show (frontend/turning.py; a crawler's wobble is about 1 deg); "
                                   "None: images only")
    turn_window_keyframes: int = Field(20, ge=2, description="keyframes over which the turn is measured (keyframes "
                                       "are spaced by image flow, about a fixed fraction of the pipe radius apart), "
                                       "at the default frontend.keyframe_min_flow_px: keyframes made further apart "
                                       "take proportionally fewer, the same length of pipe (pipeline.turn_window)")


class BundleSettings(_Section):
    """Sliding-window SBA with cylinder regularisation (fisheye paper III-C, III-D)."""

    window: int = Field(100, gt=1, description="keyframes in the sliding window")
    step: int = Field(50, gt=0, description="keyframes between window solves")
    tau: float = Field(2.5e5, ge=0, description="weight of the scene-to-cylinder error (eq. 2)")
    huber_px: float = Field(0.5, gt=0, description="Huber threshold of the reprojection error, and the least "
                            "outlier distance (tracked corners match to 0.1-0.2 px; on paper-loop 1 px let tracks "
                            "that had slipped by 0.5-1 px bend the tees: Table I 0.26 % on route A, 0.07 % at 0.5)")
    huber_m: float = Field(0.005, gt=0, description="Huber threshold of the point-to-cylinder distance")
    mad_k: float = Field(3.0, gt=0, description="outliers beyond k x 1.4826 MAD of the Huber-weighted errors")
    outlier_passes: int = Field(3, ge=0, description="iterations at which MAD outlier removal runs")
    max_iterations: int = Field(20, gt=0)
    track_age_keyframes: float | None = Field(None, gt=0, description="a window's observation counts with a pixel "
                                              "sigma of 1 + age / this, its age the keyframes since its track's "
                                              "first: the anchor match's error grows along a track "
                                              "(bench_exact_observations.py); None: every observation alike "
                                              "(at 3, paper-loop route A's T1-T4 went from -0.08 to +0.11 % on "
                                              "average over eight seeds: no better)")
    bend_knot_m: float | None = Field(0.25, gt=0, description="knot spacing of the window cylinder's bent axis (pipe "
                                      "runs sag and kink at joints by millimetres); None: a straight cylinder")
    bend_kink_deg: float = Field(0.5, gt=0, description="prior sigma of the axis's change of direction at a knot")
    bend_offset_mm: float = Field(2.0, gt=0, description="prior sigma of the axis's sideways offset from the straight "
                                  "line at a knot: joints shift a pipe's wall by millimetres, and a looser bend lets "
                                  "the heading drift (paper-loop route A: 0.4 deg per side at 10 mm, 0.2 at 2 mm)")
    bend_sag_mm: float = Field(10.0, gt=0, description="... and its vertical offset (down the camera's image, which "
                               "stays level on a crawler): pipes sag between their supports")
    tee_fit_length_m: float = Field(1.0, gt=0, description="length of pipe fitted with a straight end cylinder "
                                    "each side of a tee (the paper's 1 m); half of it where the two fits' directions "
                                    "differ beyond their noise, as when a joint beyond the piece next to the tee kinks")
    tee_model: bool = Field(True, description="join the straight sections through each tee with the two-cylinder "
                            "model SBA (III-D); off: the VO's chaining and the end cylinders' meeting point")
    tee_hold_keyframes: int = Field(10, gt=0, description="keyframes of the section before a tee in its solve, held "
                                    "where the section's VO put them")
    tee_attach_keyframes: int = Field(20, gt=0, description="keyframes of the section after a tee solved with it "
                                      "(from P_b on); later ones take the same rigid correction")
    tee_angles_deg: list[float] = Field([0.0, 90.0], description="a tee's or a cross's pipes meet at these angles "
                                        "(the run passed straight through, the branch taken); [] leaves every tee's "
                                        "angle to its solve, as the paper does")
    tee_angle_allowance_deg: float = Field(0.5, ge=0, description="... give or take this (the pipes' deflection in "
                                           "the tee's sockets): a free solve's angle further off, but within "
                                           "tee_angle_within_deg, is held at the allowance's nearer end")
    tee_angle_within_deg: float = Field(2.0, ge=0, description="a free angle further than this from every tee angle "
                                        "stands (a wye, a lateral, an 87.5 deg junction)")
    tee_hold_axes: str = Field("auto", pattern="^(auto|ends|sections)$", description="the axes a held tee angle "
                               "lies between: the end cylinders the free solve used (ends), the two sections' whole "
                               "axes (sections), or each side's end cylinder unless it turns from its section's axis "
                               "by more than tee_angle_allowance_deg (auto)")
    tee_angle_exact_codecs: list[str] = Field(["h264"], description="on video in these codecs (FFmpeg's names) from "
                                              "a camera that sees the wall beside it, a tee's solve is held at the "
                                              "tee angle itself, with no allowance: there the tracks lag the motion "
                                              "and the free solve turned every tee short, by 0.25-1.6 deg (paper-loop "
                                              "route A as H.264, seeds 1-2: Table I 4.14 / 1.23 %, held 0.55 / "
                                              "0.11 %), more than sockets deflect")
    elbow_torus: bool = Field(True, description="an elbow's solve holds the wall of its bend to a torus tangent to "
                              "both pipes' cylinders, its bend radius solved with the tee parameters (off: the bend's "
                              "wall counts by its reprojections only)")
    elbow_free_red_axis: bool = Field(True, description="an elbow's solve fits the axis of the pipe before it to "
                                      "that pipe's wall and the bend's instead of holding the straight section's end "
                                      "fit; the elbow's arc and wall piece follow the solved axes (elbow-cross: Table "
                                      "I within 0.24 % instead of 0.54 %, elbow angles within 0.20 deg instead of "
                                      "0.36)")


class StraightVOSettings(_Section):
    """Straight-section VO (fisheye paper III-C) beyond the SBA itself: what the paper leaves open."""

    min_parallax_deg: float = Field(2.0, gt=0, description="a new point needs this widest angle between its rays")
    max_ray_error_deg: float = Field(0.3, gt=0, description="... and every observed bearing within this of its ray")
    scale_min_parallax_deg: float = Field(0.5, ge=0, description="parallax of the pairs that carry the relative scale")
    min_scale_points: int = Field(8, gt=0, description="fewer points: the step keeps the previous step's length")
    first_window: int = Field(20, gt=1, description="keyframes before the first SBA and metric rescale of a section")
    fixed_overlap: int | None = Field(None, gt=0, description="hold at most this many solved poses per window (None: "
                                                              "all)")
    fixed_share: float | None = Field(0.5, gt=0, le=1, description="hold only the oldest this share of the poses "
                                      "a window has in common with solves before it (None: all). The newest "
                                      "keyframes a window solved saw their points from one side only and keep part "
                                      "of the scale the chain slipped by since the window before (compressed "
                                      "footage: 1-4 % per step over its last 10 keyframes); held, that error "
                                      "stays. Measured, all against None: H.264 straight pipe reverse leg +0.23 -> "
                                      "+0.02 %; paper-loop route A seed 1 Table I 0.29 -> 0.14 %, ATE 10.5 -> 5.6 "
                                      "mm, seed 0 0.15 -> 0.26 % (T1-T4), ATE 10.7 -> 9.3 mm")
    resection_min_points: int | None = Field(20, gt=5, description="a new keyframe's chained pose is refined "
                                             "against the scene points it sees when it sees at least this many "
                                             "(None: off): a perspective camera looking along the pipe trades "
                                             "rotation for sideways translation in its five-point pose. Only for a "
                                             "camera that does not see the wall beside it (widest colatitude below "
                                             "90 deg); a fisheye's poses hold without")
    scale_drift: float | None = Field(0.02, gt=0, description="a window solves early once the median radius of the "
                                      "points triangulated since the last solve differs from the pipe's by this "
                                      "fraction (None: only every bundle.step keyframes): a camera looking along the "
                                      "pipe can let the chained scale slip by tenths within 50 keyframes. Only for "
                                      "a camera that does not see the wall beside it (widest colatitude below 90 "
                                      "deg): a fisheye's chained scale holds, and on compressed footage the noise of "
                                      "its fresh points set the check off every few keyframes and shrank the run")
    end_lookahead: int | None = Field(None, gt=0, description="a straight section's final window waits for this "
                                      "many keyframes of the junction section after it and solves them too (None: "
                                      "it solves when the section ends): its last keyframes see wall that no later "
                                      "camera sees, and their heading drifts (bench_window_ends.py). Measured at 5 "
                                      "with end_wall_ahead_m 0.05, against None: elbow-cross B seed 2 Table I 0.238 "
                                      "-> 0.202 %, ATE 3.5 -> 2.6 mm; A seed 1 0.160 -> 0.137 %, 2.2 -> 1.9 mm; "
                                      "A seed 2 0.121 -> 0.082 %, 2.0 -> 2.1 mm; "
                                      "paper-loop route A 0.481 -> 0.228 %, 14.0 -> 7.5 mm")
    end_wall_ahead_m: float = Field(0.05, ge=0, description="... with the cylinder term on the wall up to this far "
                                    "ahead of the section's last keyframe only (the bend's wall is no cylinder; "
                                    "elbow-cross B seed 2 at 0.2: Table I 0.432 %)")
    wall_ahead_m: float | None = Field(None, ge=0, description="a window's cylinder term holds its points up to "
                                       "this far ahead of its last keyframe only (None: all): the wall further on is "
                                       "seen only by the window's last cameras, down the pipe, and where a bend "
                                       "begins it is no cylinder. At 0.02, elbow-cross on exact observations: "
                                       "Sim(3) scale 0.99975 -> 1.00002, ATE 0.86 -> 0.27 mm; tracked, five of "
                                       "six runs within 0.1 % (three by default), but paper-loop route A seed 0 "
                                       "Table I 0.040 -> 0.14 %: not the default (README, Junctions)")
    wall_inward_m: float | None = Field(0.001, gt=0, description="a window's cylinder term holds the wall ahead "
                                        "of its last keyframe only as far as no clock sector of it comes in by "
                                        "more than this (median, and by five of its standard errors) from the "
                                        "cylinder of the wall just behind: where the pipe bends ahead (None: "
                                        "all of it; backend/wall_reach.py). Paired against None, the same "
                                        "tracks: elbow-cross B seed 2 Table I 0.169 -> 0.079 %, B seed 1 0.117 "
                                        "-> 0.095 %, eight of ten junction runs within 0.1 % against seven, "
                                        "paper-loop route A seeds 0 / 1 0.040 / 0.067 -> 0.040 / 0.058 %. Only "
                                        "for a camera that sees the wall beside it (widest colatitude 90 deg or "
                                        "more): a forward camera sees only the wall ahead, and cut there cctv-"
                                        "loop route B seed 1 went 0.156 -> 0.229 %. Not on predicted video "
                                        "(H.264, MPEG-4): the codec's lag brings the wall just ahead in and "
                                        "fisheye-straight as H.264 seed 2 went -0.054 -> -0.271 % (pipeline."
                                        "straight_vo_settings)")
    wall_slice_m: float = Field(0.04, gt=0, description="length of the slices of wall ahead that wall_inward_m "
                                "judges, half-overlapping")
    whole_turn_back_m: float | None = Field(0.2, gt=0, description="a straight section in which the crawler turned "
                                            "back by more than this along the pipe is solved whole once the VO ends "
                                            "(a camera that sees the wall beside it; None: never): the windows, "
                                            "each holding poses solved before the other leg saw their wall, left "
                                            "the last 0.5 m before the turning point 0.4 % short on compressed "
                                            "footage (fisheye-straight as H.264, seeds 1 / 2, forward / reverse: "
                                            "+0.009 / +0.019, -0.054 / -0.050 -> +0.008 / +0.008, -0.039 / -0.039 %)")
    whole_max_keyframes: int = Field(400, gt=1, description="... a section of at most this many keyframes (the "
                                     "solve's camera system grows with their square; over a longer section the "
                                     "turning point's millimetre is a smaller share of the distance)")
    beside_tracking: bool = Field(True, description="run in a second process while the front end tracks, fed "
                                  "each keyframe once its class is final (the same result; not in a batch's "
                                  "runs, whose workers keep every core busy already)")
    tail_image_step: float | None = Field(1.6, gt=1, description="the rescale of a window's not yet solved "
                                          "keyframes is refused when it takes their steps further than this "
                                          "factor (and further than before) from the steps their features' image "
                                          "motion shows (section_vo._steps_agree; None: off)")
    min_window_points: int = Field(30, gt=0, description="fewer points: no window solve")
    min_window_keyframes: int = Field(3, gt=1)
    max_colatitude_deg: float | None = Field(70.0, gt=0, le=180, description="window observations beyond this angle "
                                             "from the optical axis are left out (None: all): towards the lens rim "
                                             "the robot's own light falls off steeply, fixed in the image, and "
                                             "tracked corners drift inwards (at 640x480 after 4-8 keyframes: "
                                             "-0.02 px at 70-80 deg, -0.06 px at 80-90 deg; evenly lit, -0.01 px), "
                                             "which shortens the scale")


class EvidenceSettings(_Section):
    """Which junction passes are junctions (backend/evidence.py): where the axis runs straight on, a side
    branch's wall must show in the points around the pass (backend/side_opening.py), and places it."""

    opening_min_points: int = Field(30, gt=3, description="points on the branch wall that show a side opening")
    opening_reach_radii: float = Field(2.0, gt=0, description="branch-wall points are looked for up to this many "
                                       "pipe radii beyond the through pipe's wall, and as far along it either side "
                                       "of the junction frames' centre (plus one radius)")
    opening_max_sigma_radii: float = Field(0.02, gt=0, description="the opening places the tee only when its centre "
                                           "along the pipe is known to this fraction of the radius (1 sigma)")


class LoopClosureSettings(_Section):
    """Loop closure by pose-graph optimisation (fisheye paper III-E)."""

    enabled: bool = Field(True, description="close loops where the route revisits a straight section")
    candidates_per_section: int = Field(10, gt=0, description="pose pairs per revisited section (paper: 15 in all)")
    # Which sections are one pipe visited twice, and which poses pair up (the paper counts turns).
    same_pipe_angle_deg: float = Field(5.0, gt=0, description="axes of one pipe's visits differ by less than this")
    same_pipe_offset_radii: float = Field(2.0, gt=0, description="... and lie closer than this many radii apart "
                                          "(distinct parallel pipes are at least 2 apart)")
    same_junction_radii: float = Field(2.0, gt=0, description="a tee pass within this many radii of an earlier "
                                       "tee's centre is a revisit of it (one entry in junctions.yaml)")
    min_overlap_m: float = Field(0.2, ge=0, description="... and overlap along the axis by at least this much; "
                                 "a crawler that goes back more than this within a section starts a second visit "
                                 "of its pipe (backend/revisit.section_legs)")
    pairing_tolerance_m: float = Field(0.03, gt=0, description="a pair's distances to the tee, l_i and l_j, "
                                       "differ by less than this")
    # Relative pose of a pair (what the paper leaves open).
    match_ratio: float = Field(0.8, gt=0, le=1, description="SIFT nearest / second-nearest distance ratio, both ways")
    sift_size_px: float = Field(8.0, gt=0, description="SIFT keypoint size (px at frontend.reference_px_per_deg, "
                                                       "scaled like the front end's sizes)")
    min_inliers: int = Field(20, gt=5, description="fewer matches agreeing with the metric pose: no edge")
    wall_window_radii: float = Field(2.5, gt=0, description="wall points within this many radii along the pipe "
                                     "of the camera carry the metric scale")
    min_sigma_m: float = Field(0.001, ge=0, description="added to an edge's translation sigma (wall-fit error)")
    min_sigma_deg: float = Field(0.02, ge=0, description="added to an edge's rotation sigma")
    # The pose graph.
    junction_edges: bool = Field(True, description="a tee passed twice ties its two passes' keyframes in the pose "
                                 "graph: both measured the same tee frame (centre, through axis, branch), "
                                 "backend/junction_loops.py")
    junction_sigma_m: float = Field(0.003, gt=0, description="sigma of a pass's tee centre in such an edge")
    junction_sigma_deg: float = Field(0.5, gt=0, description="sigma of a pass's tee axes in such an edge")
    odometry_sigma_m: float = Field(0.01, gt=0, description="odometry translation sigma after one metre (per sqrt m)")
    odometry_sigma_deg: float = Field(0.5, gt=0, description="odometry rotation sigma after one metre (per sqrt m)")
    robust_kernel: Literal["huber", "cauchy", "none"] = Field("huber", description="on loop-closure edges")
    kernel_width: float = Field(2.0, gt=0, description="kernel threshold in standard deviations of an edge")


class AppearanceSettings(_Section):
    """Dense grey-level appearance map (fisheye paper IV-B) and unrolled wall images."""

    enabled: bool = Field(True, description="write appearance.ply and unrolled/ in pipemap run")

    spacing_m: float = Field(0.002, gt=0, description="point spacing on the fitted cylinders")
    min_theta_deg: float | None = Field(None, ge=0, description="use pixels with colatitude above this ... (None: 5/9 "
                                        "of the upper limit, the paper's 50 deg on its 190 deg fisheye)")
    max_theta_deg: float | None = Field(None, gt=0, description="... and below this (None: 90 deg, or the widest "
                                        "colatitude the camera's image holds when that is less)")
    edge_taper_deg: float = Field(5.0, ge=0, description="samples are weighted up from 0 over this many degrees inside "
                                  "either colatitude limit, so that keyframe band edges leave no seams (0: plain mean)")
    unrolled_px_m: float = Field(0.002, gt=0, description="metres per pixel of unrolled wall images")
    exposure_normalise: bool = Field(True, description="divide each keyframe image by its median grey level in the "
                                     "band before sampling, so that auto-exposure steps and drift leave no bands "
                                     "(mapping/exposure.py)")


class DeformationSettings(_Section):
    """Ovality, diameters and dents of the straight pieces every slice_m (laser profilers' 10 cm, ASTM F3080),
    from the sparse points triangulated again without the cylinder term, and from the dense wall search."""

    enabled: bool = Field(True, description="write deformation.csv and deformation.png in pipemap run")
    slice_m: float = Field(0.1, gt=0, description="spacing of the slices along each straight piece")
    sparse_band_m: float = Field(0.05, gt=0, description="sparse points within this of a slice's h count for it")
    harmonics: int = Field(4, ge=2, le=12, description="Fourier terms of r(phi) fitted per slice (2: an ellipse)")
    min_points: int = Field(40, ge=8, description="fewest points a slice needs (after outliers)")
    min_cover_deg: float = Field(300.0, gt=0, le=360, description="a slice's points must cover this much of the "
                                 "circle (in 10 deg bins)")
    bin_deg: float = Field(8.0, gt=0, le=45, description="dense ring: width around of the cells whose medians give "
                           "the largest inward and outward deviation (a dent)")
    dent_grid_m: float = Field(0.01, gt=0, description="sparse wall field: node spacing along and around at which "
                               "the deviation is estimated")
    dent_neighbours: tuple[int, ...] = Field((20, 40, 80), min_length=1, description="sparse wall field: the "
                                             "neighbourhoods (nearest points) of the local quadratic fits, of which "
                                             "ICI picks one per node")
    dent_ici_gamma: float = Field(1.0, gt=0, description="sparse wall field: ICI keeps the widest neighbourhood "
                                  "whose estimate +- this many SDs meets every narrower one's")
    dent_outlier_mads: float = Field(5.0, gt=0, description="sparse wall field: points farther than this many robust "
                                     "SDs from their neighbours' local quadratic are dropped")
    dent_reach_m: float = Field(0.02, gt=0, description="sparse wall field: no value where the nearest point lies "
                                "farther than this (a gap)")
    centre_window_m: float = Field(0.25, gt=0, description="the slices' centre offsets are smoothed along the piece "
                                   "over +- this (the axis bends slowly; a dent is local)")
    outlier_mads: float = Field(4.0, gt=0, description="points farther than this many MADs from a slice's fit are "
                                "dropped")
    min_parallax_deg: float = Field(2.0, gt=0, description="sparse re-triangulation: the widest angle between a "
                                    "point's rays")
    max_ray_error_deg: float = Field(0.15, gt=0, description="sparse re-triangulation: drop points whose ray "
                                     "misses an observation by more than this")
    dense: bool = Field(False, description="also measure the wall's radius densely by photo-consistency (a "
                        "sweep along the wall normal per cell of each slice's ring, wall_depth.py)")
    dense_search_m: float = Field(0.02, gt=0, description="dense search: +- this around the a-priori radius")
    dense_step_m: float = Field(0.002, gt=0, description="dense search: radius step (the least cost is refined "
                                "by a parabola)")
    dense_cell_m: float = Field(0.01, gt=0, description="dense search: spacing of the cells around the ring")
    dense_patch_m: float = Field(0.015, gt=0, description="dense search: side of a cell's wall patch")
    dense_sample_m: float = Field(0.0015, gt=0, description="dense search: spacing of the patch's samples")
    dense_subsamples: int = Field(1, ge=1, le=4, description="dense search: each sample averages this many "
                                  "points squared over its square of wall (area sampling)")
    dense_rings: int = Field(3, ge=1, description="dense search: rings of cells per slice, side by side along "
                             "the pipe, fitted together")
    dense_views: int = Field(5, ge=2, description="dense search: views per cell, the reference among them")
    dense_ref_deg: float = Field(45.0, gt=0, lt=90, description="dense search: the reference view sees the cell "
                                 "nearest this far off its axis")
    dense_parallax_deg: float = Field(10.0, gt=0, description="dense search: the other views see the cell at "
                                      "least this much nearer the side than the reference")
    dense_max_deg: float = Field(90.0, gt=0, le=180, description="dense search: and at most this far off axis")
    dense_min_zncc: float = Field(0.6, ge=-1, le=1, description="dense search: a cell whose best median "
                                  "correlation is lower has no radius")


class DenseSettings(_Section):
    """Dense straight-pipe VO (2010 report section 4)."""

    scale: float | None = Field(None, gt=0, le=1, description="image reduction; None = the report's quarter "
                                                              "resolution, "
                                "or less reduced where a quarter-resolution pixel would cover more than "
                                "wall_mm_per_px of the wall")
    wall_mm_per_px: float = Field(1.0, gt=0, description="scale = None: the coarsest sampling of the wall (mm per "
                                  "pixel at the principal point) the reduction may give")
    metric: Literal["sad", "ssd", "zncc"] = "zncc"
    search_px: int = Field(16, gt=0, description="full-search range to start with (+/- px at reduced resolution, "
                           "around the shift predicted from the previous pair); doubled while the best match lies "
                           "on its edge or correlates below search_min_zncc")
    search_min_zncc: float = Field(0.5, ge=-1, le=1, description="full search: a best match whose ZNCC is below this "
                                   "widens the range")
    pyramid_levels: int = Field(3, gt=0, description="hierarchical Lucas-Kanade levels")
    lk_iterations: int = Field(10, gt=0)
    pixels_per_metre: float | None = Field(None, gt=0, description="zeta, the reference scale (report section 3.3); "
                                           "None = from calibration, radius and the camera's offset from the axis")
    camera_offset_m: float | None = Field(
        None, description="camera displacement from the pipe axis along its principal axis, + towards the viewed "
        "wall, as measured on the robot (zeta from geometry); None = the estimated mount's offset (mount = estimate) "
        "or on the axis (mount = square)")
    mount: Literal["estimate", "square"] = Field(
        "estimate", description="estimate = the camera's rotation and offset in the pipe from the sparse method's "
        "initial batch over the first frames (straight/mount.py); each frame is turned to a virtual camera square to "
        "the wall with image x along the pipe, and the offset sets zeta unless a reference is given; square = the "
        "report's assumption that the camera already looks square at the wall with image x along the pipe")
    offset_station_m: float | None = Field(
        0.3, ge=0, description="mount = estimate, no reference or offset given: the offset is measured again every "
        "this many metres of travel (the sparse bundle batch over a few keyframes) and each pair scaled by the wall "
        "distance of its part of the run, since the robot rides up and down by millimetres (straight/stations.py); "
        "None or 0 = the first frames' offset for the whole run")
    offset_station_max_tilt_deg: float = Field(3.0, gt=0, description="a station whose pipe axis (in the camera's "
                                               "axes) is turned further than this from the run's mount is left out: "
                                               "the camera is fixed to the robot, which wobbles by a degree or so")
    rerectify_min_pct: float | None = Field(0.02, gt=0, description="with offset stations: where turning the view "
                                            "from the first frames' mount to the stations' mean pipe axis changes the "
                                            "scale by more than this (per cent; a view tilted along the pipe by delta "
                                            "scales its motion by 2 delta tan(theta) at theta off its principal point: "
                                            "0.29 % at a 75 deg mount for 0.24 deg), the frames are turned to it and "
                                            "registered again; None: never")
    resample_rows: bool = Field(True, description="zeta from geometry: resample every row of the view along the "
                                "pipe by its wall depth so that an axial move shifts all rows alike (on a curved wall "
                                "they move up to 7 % apart and a single translation fits none; undistort.py); False = "
                                "the report's view, its rows' zetas weighted by their texture")
    rectify_max_angle_deg: float = Field(60.0, gt=0, lt=90, description="mount = estimate: the view turned square "
                                         "to the wall reaches this far along the pipe from square (beyond, one pixel "
                                         "of an oblique camera spreads over several)")
    search_y_px: int | None = Field(None, ge=0, description="full-search range across the pipe; None = search_px // 2")
    band_fraction: float = Field(0.5, gt=0, le=1, description="central fraction of the rows that is registered")
    predict: bool = Field(True, description="search around / start from the previous pair's shift (constant velocity)")
    lk_tolerance_px: float = Field(1e-3, gt=0, description="Gauss-Newton stops when the update is below this")
    gain_correct: bool = Field(True, description="divide by the dataset's gain mask when it has one (section 3.2)")
    light_sigma_px: float | None = Field(
        4.0, gt=0, description="without a gain mask, every rectified frame is divided by its own Gaussian blur of "
        "this sigma (px): the LEDs' light stays put in the image while the wall moves, and holds the registration "
        "back towards no motion; None = the frames as they are")
    stitch_min_shift_px: float = Field(50.0, ge=0, description="frames stitched into the unrolled wall are at least "
                                       "this far apart along the pipe (report: 50 px)")
    unrolled_px_m: float | None = Field(None, gt=0, description="metres per pixel of the unrolled wall; None: one "
                                        "camera pixel at the first frame's principal point")
    unrolled_max_px: int = Field(8000, gt=16, description="longest side of the unrolled image (coarser pixels beyond)")
    full_search_reference_fraction: float | None = Field(
        0.2, gt=0, lt=0.5, description="full search: register against a reference frame until the content has "
        "moved this fraction of the image width, so that integer rounding errs once per reference rather than "
        "once per frame (a steady speed rounds the same way every frame); None = adjacent frames (Algorithm 1)")


class SparseSettings(_Section):
    """Sparse cylinder-constrained VO (2010 report section 5)."""

    grid: tuple[int, int] = Field((6, 8), description="region Harris grid rows x cols")
    corners_per_cell: int = Field(20, gt=0)
    nms_px: int = Field(7, gt=0, description="non-maximum suppression window")
    sigma_w: float = Field(3.0, gt=0, description="Harris integration scale")
    sigma_d: float = Field(1.5, gt=0, description="Harris derivative scale")
    harris_k: float = Field(0.04, gt=0)
    light_sigma_px: float | None = Field(
        12.0, gt=0, description="without a gain mask, keypoints and descriptors are taken on the image divided by "
        "its own Gaussian blur of this sigma, which removes the LEDs' fall-off that moves with the camera and drags "
        "Harris corners against the motion (a scale bias of 0.1-0.2 %); None = the image as it is")
    ambiguity_ratio: float = Field(0.8, gt=0, le=1, description="SIFT ambiguity ratio with mutual check")
    match_patch_px: int | None = Field(15, ge=5, description="side of the patch (odd) that places each match in the "
                                       "new keyframe by registering the previous keyframe's patch around it (affine "
                                       "Lucas-Kanade); None keeps the Harris peaks found in each image")
    match_iterations: int = Field(10, gt=0, description="Lucas-Kanade iterations of that registration")
    keyframe_min_matches: int = Field(100, gt=0)
    keyframe_max_flow_px: float = Field(20.0, gt=0)
    offset_batch_keyframes: int = Field(10, gt=1, description="keyframes of the initial offset C_X, C_Y batch")
    offset_batch_model: Literal["bundle", "report"] = Field(
        "bundle", description="bundle: every batch keyframe's 6-DOF pose, the wall points and the axis's offset and "
        "tilt by bundle adjustment on the wall (sparse/batch.py); report: eqs. 45-49 as printed, all keyframes at R0")
    offset_wall_sigma_m: float = Field(1e-4, gt=0, description="bundle batch: points may leave the wall by about this "
                                       "per pixel of reprojection error (the stiffness of the known radius)")
    offset_batch_iterations: int = Field(50, gt=0, description="bundle batch: Levenberg-Marquardt iterations")
    max_incidence_deg: float | None = Field(
        60.0, gt=0, le=90, description="bundle batch and sliding bundle: observations of wall seen more than this far "
        "from its normal are left out (registered from keyframe to keyframe, a match there moves 0.4 % further "
        "than the wall at 60-65 deg, 2 % at 65-70, against 0.05 % up to 60; None keeps all)")
    offset_huber_px: float = Field(1.0, gt=0, description="bundle batch and sliding bundle: Huber threshold of the "
                                   "reprojection error")
    offset_mad_k: float = Field(3.0, gt=0, description="bundle batch and sliding bundle: outliers beyond k x 1.4826 "
                                "MAD of the reprojection errors")
    offset_outlier_passes: int = Field(3, ge=0, description="bundle batch and sliding bundle: MAD outlier passes")
    offset_max_sigma: float = Field(0.003, gt=0, description="bundle batch: the offset counts as determined when its "
                                    "standard deviation is within this fraction of the camera's distance to the wall "
                                    "(that fraction is the scale error it brings)")
    offset_measured: bool = Field(False, description="initial_offset_m was measured on the robot (as in the report): "
                                  "kept when the batch cannot determine the offset (narrow lens, large pipe)")
    offset_long_keyframes: int = Field(100, gt=1, description="the bundle batch again over this many keyframes, "
                                       "kept where its offset's sigma is smaller than the first batch's and within "
                                       "offset_max_sigma; where neither bundle estimate is within it and none was "
                                       "measured, eqs. 45-49 over them, kept where offset_report_max_z admits them, "
                                       "else the bundle estimate with the smaller sigma (<= offset_batch_keyframes: "
                                       "off)")
    offset_report_max_z: float = Field(3.0, gt=0, description="long batch: eqs. 45-49 replace the better bundle "
                                       "estimate of an undetermined offset only where they lie within this many of "
                                       "its standard deviations of it (they hold every keyframe at one rotation, "
                                       "so a robot's wobble biases them; a bundle estimate that rules their value "
                                       "out is kept)")
    offset_long_lag: int = Field(10, gt=0, description="long batch: pairs of keyframes at most this far apart")
    offset_long_step: int = Field(3, gt=0, description="long batch: the bundle batch takes every this-th keyframe (the "
                                  "span of wall seen fixes the offset, not the number of keyframes); eqs. 45-49 "
                                  "over all of them")
    refine_every: int = Field(50, gt=0, description="N: 6-DOF sliding refinement over the previous 2N")
    refine_passes: int = Field(2, gt=0)
    refine_dof: Literal["auto", "six", "crawler", "bundle"] = Field(
        "auto", description="sliding refinement: six = every pose in all six degrees of freedom against S(g), one "
        "after the other (the report); bundle = the 2N keyframes (every offset_long_step-th) together with their "
        "points in one bundle adjustment on the wall (sparse_batch.bundle_window); crawler = only the robot's roll "
        "about the axis and its travel along it, its camera mount held as the offset batch left it "
        "(sparse_motion.refine_crawler); auto = crawler where the batch found the images cannot determine the "
        "camera's offset (narrow lens, large pipe: they cannot fix pitch or the distance to the wall either), else "
        "bundle")
    # What the report leaves open.
    gain_correct: bool = Field(True, description="divide by the dataset's gain mask when it has one (section 3.2)")
    initial_offset_m: tuple[float, float] = Field(
        (0.0, 0.0), description="start of the C_X, C_Y batch (the report measured it by hand; 0 = on the axis)")
    initial_mount: Literal["motion", "square"] = Field(
        "motion", description="start of the bundle batch: square = the report's R0 (optical axis square to the wall, "
        "image x along it); motion = also from the camera turned to travel along the pipe as the five-point pose "
        "between the batch's first and last keyframes says it does, keeping the better fit (any mount, square to "
        "the wall down to looking well ahead)")
    ransac_threshold_px: float = Field(1.0, gt=0, description="five-point RANSAC inlier threshold (px at the centre)")
    min_inliers: int = Field(15, gt=5, description="fewer RANSAC inliers: the keyframe pair keeps no matches")
    outlier_mad_k: float = Field(3.0, gt=0, description="an estimate farther than k x 1.4826 x the median distance "
                                 "from its point's mean leaves the point (a mismatch)")
    outlier_floor_m: float = Field(2e-4, ge=0, description="... but never closer than this")
    lm_iterations: int = Field(20, gt=0, description="Levenberg-Marquardt iterations per pose")
    refine_at_end: bool = Field(True, description="also refine the last 2N keyframes when the run ends")
    unrolled_px_m: float | None = Field(None, gt=0, description="metres per pixel of the unrolled wall; "
                                        "None = the wall footprint of the first keyframe's centre pixel")
    unrolled_max_px: int = Field(8000, gt=16, description="longest side of the unrolled image (coarser pixels beyond)")


class GainMaskSettings(_Section):
    """White-card gain mask (2010 report section 3.2)."""

    sigma_px: float = Field(15.0, gt=0, description="Gaussian smoothing of the averaged white-card images")


class RouteSettings(_Section):
    """Inspector's coordinates: chainage along the route's axis and clock position around it (inspection/)."""

    up: Literal["image", "camera-side"] | tuple[float, float, float] = Field(
        "image", description="12 o'clock: `image` = the keyframes' mean image-up across the axis (a crawler keeps "
        "its roll), `camera-side` = opposite the camera's mean offset from the axis (it rides the invert), or a "
        "world vector [x, y, z] in the frame of trajectory.tum")


class LocateSettings(_Section):
    """Uncertainty of a located wall point (pipemap locate / observations): first-order propagation of these."""

    pixel_sigma_px: float = Field(1.0, ge=0, description="the inspector's pixel")
    position_sigma_m: float = Field(0.002, ge=0, description="camera centre across and along the axis, locally")
    drift_fraction: float = Field(0.002, ge=0, description="scale drift of the VO: chainage sigma grows by this "
                                  "fraction of the chainage (Table I errors of the network pipeline: under 0.2 %)")
    rotation_sigma_deg: float = Field(0.2, ge=0, description="camera orientation, each axis")
    radius_sigma_m: float = Field(0.001, ge=0, description="the pipe's radius about the a-priori value")
    register_frames: bool = Field(True, description="orient a frame between keyframes by registering its image to "
                                  "the nearest keyframe's (when the run's dataset can be read), not by slerp")
    register_threshold_px: float = Field(2.0, gt=0, description="inlier threshold of that registration's five-point "
                                         "MSAC, in pixels at the image centre")


class QualitySettings(_Section):
    """Self-checks from the data alone: what is too little to map, and when a section is suspect or failed."""

    min_frames: int = Field(10, gt=1, description="fewer readable frames (repeats not counted): nothing to map")
    min_lit_fraction: float = Field(0.05, ge=0, le=1, description="a frame whose pixels brighter than "
                                    "frontend.dark_level are fewer than this fraction is dark (lights off)")
    min_texture: float = Field(1.5, ge=0, description="a frame whose lit pixels vary by less than this (grey-level "
                               "standard deviation after removing the lighting) shows no wall texture")
    min_keyframes: int = Field(3, gt=1, description="a section with fewer keyframes is suspect; a run with fewer "
                               "in all maps nothing")
    rms_px: tuple[float, float] = Field((1.0, 2.5), description="reprojection RMS of a section's window solves "
                                        "(median): suspect above the first, failed above the second")
    cylinder_rms: tuple[float, float] = Field((0.02, 0.05), description="RMS distance of a section's points from "
                                              "its wall, as a fraction of the radius: suspect, failed")
    free_radius: tuple[float, float] = Field((0.02, 0.05), description="the radius of a section's points "
                                             "triangulated from its poses alone (no wall term) against the "
                                             "given radius, relative difference: suspect, failed (a scale "
                                             "problem)")
    min_free_radius_points: int = Field(30, gt=0, description="fewer triangulated points: no free radius")
    image_step: tuple[float, float] = Field((1.05, 1.25), description="the factor (either way) between a "
                                            "straight section's keyframe steps and the steps its features' image "
                                            "motion shows on its fitted wall (median over a stretch of "
                                            "image_step_keyframes): suspect, failed (frontend/image_steps.py: a "
                                            "scale that shrank with its points). Measured: 1.000-1.014 on 640x480 "
                                            "CCTV, 1.001-1.003 paper-loop, 1.02-1.025 fisheye H.264")
    image_step_keyframes: int = Field(10, ge=3, description="keyframes of a stretch of that comparison")
    unexplained_turn_deg: float = Field(2.0, gt=0, description="a junction section dropped for showing no junction "
                                        "(no side opening, its axes turning less than a tee's or an elbow's) whose "
                                        "axes still turn by more than this is suspect: a gentle bend the map has no "
                                        "model for, or a turn the tracking made (joints deflect by a degree or so)")
    tee_angle_off_deg: float = Field(0.5, gt=0, description="a tee whose free solve turned further than this from "
                                     "the tee angle it was held at (bundle.tee_angles_deg) is suspect: more than its "
                                     "sockets deflect, so the tracking through it turned it")
    tracked_share: tuple[float, float] = Field((0.5, 0.25), description="a section's median fraction of the "
                                               "previous keyframe's features tracked on, as a share of the run's "
                                               "median (the lens sets the usual value): suspect below the first, "
                                               "failed below the second")
    loop_correction: tuple[float, float] = Field((0.01, 0.03), description="largest pose correction of loop "
                                                 "closure as a fraction of the route's length: suspect, failed")
    registration_zncc: float = Field(0.5, description="dense methods: a frame pair registered with a lower "
                                     "similarity is a weak link")
    weak_links: tuple[float, float] = Field((0.02, 0.1), description="dense methods: fraction of weak links: "
                                            "suspect, failed")
    mount_sigma: tuple[float, float] = Field((0.005, 0.015), description="straight-pipe methods: the estimated "
                                             "offset's standard deviation as a fraction of the distance to the "
                                             "wall, which is the scale's own: suspect above the first (two sigma "
                                             "reach 1 % of distance), failed above the second")


class ViewerSettings(_Section):
    """The self-contained viewer page (`pipemap report`)."""

    cloud_points: int = Field(200_000, ge=0, description="appearance points drawn in the 3D view: a seeded random "
                              "sample of appearance.ply (a paper-loop map holds about 10 million; 0: none)")


class BatchSettings(_Section):
    """`pipemap batch`: many datasets, one Dask task each. Only the batch's own --config / --set reach these."""

    workers: int | None = Field(None, gt=0, description="workers of the local Dask cluster, one run at a time each "
                                "(None: one per core); a cluster at --scheduler has its own")
    threads_per_run: int | None = Field(1, gt=0, description="OpenCV and BLAS/OpenMP threads of one run on a worker: "
                                        "with one, a worker per core keeps every core on its own run, where more "
                                        "threads only wait on one another (None: the libraries' own choice)")
    retries: int = Field(3, ge=0, description="times a run is started again on another worker when its worker dies "
                         "under it (the local scheduler's allowed-failures); a run that fails on its input is not "
                         "retried")
    processes: bool = Field(True, description="local workers are processes (False: threads of the batch's own "
                            "process, which start at once but share one interpreter)")


class Settings(_Section):
    seed: int = Field(0, description="seed of every random choice (RANSAC, sampling)")
    frontend: FrontendSettings = FrontendSettings()
    classification: ClassificationSettings = ClassificationSettings()
    bundle: BundleSettings = BundleSettings()
    straight_vo: StraightVOSettings = StraightVOSettings()
    evidence: EvidenceSettings = EvidenceSettings()
    loop_closure: LoopClosureSettings = LoopClosureSettings()
    appearance: AppearanceSettings = AppearanceSettings()
    deformation: DeformationSettings = DeformationSettings()
    dense: DenseSettings = DenseSettings()
    sparse: SparseSettings = SparseSettings()
    gain_mask: GainMaskSettings = GainMaskSettings()
    quality: QualitySettings = QualitySettings()
    route: RouteSettings = RouteSettings()
    locate: LocateSettings = LocateSettings()
    viewer: ViewerSettings = ViewerSettings()
    batch: BatchSettings = BatchSettings()

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")

    def recorded(self) -> dict[str, Any]:
        """The settings a result records: all but `batch`, which spreads runs over workers and changes no map."""
        return self.model_dump(mode="json", exclude={"batch"})


def _first_error(exc: ValidationError) -> tuple[str, str]:
    err = exc.errors()[0]
    return ".".join(str(p) for p in err["loc"]), err["msg"]


def load_settings(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Settings:
    """Defaults, then a YAML file, then `section.key=value` overrides (values parsed as YAML)."""
    data: dict[str, Any] = {}
    where = "--set"
    if path is not None:
        where = str(path)
        loaded = read_yaml(path, "settings file", mapping=False)
        if loaded is not None and not isinstance(loaded, dict):
            raise PipemapError("expected a mapping of sections", path)
        data = loaded or {}
    for item in overrides:
        if "=" not in item:
            raise PipemapError(f"expected section.key=value, got {item!r}", "--set")
        key, raw = item.split("=", 1)
        parts = key.strip().split(".")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            value = raw
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise PipemapError(f"{p} is not a section", "--set", key)
        node[parts[-1]] = value
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        key, msg = _first_error(exc)
        raise PipemapError(msg, where, key) from None


def save_settings(path: str | Path, settings: Settings) -> None:
    Path(path).write_text(yaml.safe_dump(settings.to_dict(), sort_keys=False))
