"""Every tunable of the pipeline, in one validated object with documented defaults.

The paper fixes some values (likelihood means, prior, AIB delta, kNN filter) and leaves others
open (depth tolerance, crop background, null task rule...). All of them live here so a job record
can carry its exact parameters and a result can report them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

PAPER_MU0 = 0.20
"""Mean cosine score of irrelevant (task, segment) pairs in the paper (Sec. 4.2, FastSAM segments);
the likelihood falls back on it when neither the job nor the model's calibration sets `mu0`."""
PAPER_MU1 = 0.27
"""Mean score of relevant pairs in the paper (tuned); the fallback for `mu1`."""
PAPER_S = 0.035
"""Std shared by both likelihoods in the paper (from COCO positives); the fallback for `s`."""
FORMER_FUSION_BACKENDS = {"torch": "auto", "numpy": "cpu"}
"""`fusion_backend` values of the numpy/torch twins, mapped to the device that now runs the one
implementation where each ran ('torch' ran on the render device, 'numpy' on the host)."""


Reader = Literal["job", "perceive", "fuse", "cluster"]
CacheName = Literal["perception", "visibility", "alignment"]
"""A content-keyed cache (`job.stage_table.CACHES`, by the name of its folder)."""
"""Who reads a parameter: a stage of `job.stage_table.STAGE_TABLE`, or "job" for what every stage
reads through the job itself (which frames, which device)."""


@dataclass(frozen=True)
class ReadBy:
    """Which stage reads a parameter, written in the parameter's own annotation.

    Why beside the field and not in a list elsewhere: a new parameter cannot be added without
    saying who reads it, and everything that needs the answer derives it from here: the cache
    keys (`stage_table`: a cache's parameters are the fields whose `keys` name it), `bfields
    params` and the docs' parameter table (its "read by" column), and the rule that lengths are
    read only through `scene.scale.SceneLengths` (`length`; tests/core/test_param_readers.py).

    stage: the stage that reads it (module docstring of `Reader`).
    also: the other stages that read it (`prior`: the cluster stage's per-view conditionals;
        the likelihood's `mu0`, `mu1`, `s`, `s_eps`: its answer threshold; `fusion`: whether
        it counts views). Every stage that reads a field must be named here or in `stage`:
        tests/core/job/test_param_readers_by_behaviour.py runs the stages and records who reads what.
    why: what the stage reads it for, in two or three words (shown in `bfields params`).
    keys: the caches whose content key the value enters (it changes what they hold: a change
        must miss them); a field that keys no cache must not change any cache entry.
    length: a length (or the scale lengths are fractions of) that `scene_lengths` resolves once
        per run; code reads the resolved `SceneLengths`, never the raw field.
    """

    stage: Reader
    why: str
    keys: tuple[CacheName, ...] = ()
    length: bool = False
    also: tuple[Reader, ...] = ()

    @property
    def stages(self) -> tuple[Reader, ...]:
        """Every stage that reads the field: `stage` first, then `also`."""
        return (self.stage, *self.also)


class PipelineParams(BaseModel):
    """Parameters of the three stages. Unknown fields are rejected so typos fail loudly.

    Every number is finite (NaN / Infinity are refused, never turned into null) and bounded: the
    upper limits are far above any useful value but keep a hostile or mistyped number (a `top_k`
    of 10^18) from ever reaching an allocation. The CLI (`--param`, `--params`) and the service
    validate through this one class, so both refuse the same values with the same message."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    # --- frames -----------------------------------------------------------------------------
    frame_stride: Annotated[int, ReadBy("job", "selects frames")] = Field(
        1, ge=1, le=10_000, description="Use every n-th frame of the capture."
    )
    max_frames: Annotated[int | None, ReadBy("job", "selects frames")] = Field(
        None, ge=1, le=1_000_000, description="Use at most this many frames (after stride)."
    )

    # --- alignment check before perception (checks/alignment.py explains the scores) -----------
    alignment_check: Annotated[bool, ReadBy("perceive", "alignment check")] = Field(
        True, description="Refuse a scene whose splat does not line up with its cameras and photos."
    )
    alignment_min_frustum_share: Annotated[
        float, ReadBy("perceive", "alignment check", keys=("alignment",))
    ] = Field(
        0.5,
        ge=0,
        le=1,
        description="Least opacity-weighted share of the Gaussians inside at least one camera frustum.",
    )
    alignment_max_extent_ratio: Annotated[
        float, ReadBy("perceive", "alignment check", keys=("alignment",))
    ] = Field(
        200.0,
        gt=1,
        le=1e9,
        description="Splat extent / camera baseline must lie in [1/r, r] (a unit or scale mix-up otherwise).",
    )
    alignment_min_score: Annotated[float, ReadBy("perceive", "alignment check", keys=("alignment",))] = Field(
        0.35,
        ge=-1,
        le=1,
        description="Least median render-vs-photo score (alpha-weighted ZNCC of band-passed grey).",
    )
    alignment_frames: Annotated[int, ReadBy("perceive", "alignment check", keys=("alignment",))] = Field(
        4, ge=1, le=1000, description="Frames rendered by the check, spread evenly over the capture."
    )
    alignment_max_side: Annotated[int, ReadBy("perceive", "alignment check", keys=("alignment",))] = Field(
        160, ge=16, le=4096, description="Longest image side (pixels) the check renders and compares at."
    )

    # --- likelihood (METHOD step 3); None means: take it from the model's calibration ------------
    mu0: Annotated[float | None, ReadBy("fuse", "fusion update", also=("cluster",))] = Field(
        None,
        ge=-1,
        le=1,
        description=f"Mean cosine score of irrelevant segments; None: the model's calibration, else the paper's {PAPER_MU0:.2f}.",
    )
    mu1: Annotated[float | None, ReadBy("fuse", "fusion update", also=("cluster",))] = Field(
        None,
        ge=-1,
        le=1,
        description=f"Mean cosine score of relevant segments; None: the model's calibration, else the paper's {PAPER_MU1:.2f}.",
    )
    s: Annotated[float | None, ReadBy("fuse", "fusion update", also=("cluster",))] = Field(
        None,
        gt=0,
        le=1,
        description=f"Std of both likelihoods; None: the model's calibration, else the paper's {PAPER_S}.",
    )
    s_eps: Annotated[float, ReadBy("fuse", "fusion update", also=("cluster",))] = Field(
        0.0, ge=0, le=1, description="Extra measurement noise std added in quadrature to s."
    )
    prior: Annotated[float, ReadBy("fuse", "fusion update", also=("cluster",))] = Field(
        0.05, gt=0, lt=1, description="Prior probability that a Gaussian is relevant to a task."
    )

    crop_batch_size: Annotated[int, ReadBy("perceive", "runtime")] = Field(
        64,
        ge=1,
        le=4096,
        description=(
            "Mask crops per encoder call, pooled across consecutive frames (bounds model memory; "
            "at most 4096: a batch of 4096 224-px crops is already ~2.5 GB of float32 input)."
        ),
    )
    prefetch_frames: Annotated[int, ReadBy("perceive", "runtime")] = Field(
        2,
        ge=0,
        le=64,
        description=(
            "Frames each perception step (decode, segment, crop) may run ahead of encoding; 0 = no "
            "threads. At most 64: each frame ahead holds its decoded image and masks in memory."
        ),
    )

    # --- fusion (steps 4-5) ----------------------------------------------------------------------
    fusion: Annotated[Literal["bayes", "average"], ReadBy("fuse", "fusion update", also=("cluster",))] = (
        Field(
            "bayes",
            description="'bayes' = the method; 'average' = ablation averaging cosine scores then Eq. 3.",
        )
    )
    outlier_rejection: Annotated[bool, ReadBy("fuse", "fusion update")] = Field(
        True, description="OR-phi: skip masks that would lower every task's probability."
    )
    view_correlation: Annotated[float, ReadBy("fuse", "fusion update")] = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description=(
            "rho: correlation of one Gaussian's score errors across its views. 0 = the paper (views "
            "independent, evidence grows with every view); rho > 0 divides a Gaussian's summed "
            "evidence by 1 + (n - 1) rho for its n accepted views (equicorrelated Gaussian "
            "likelihood; 1 = all views one measurement). Docs: The capture suite, Correlated views."
        ),
    )
    depth_source: Annotated[
        Literal["median", "expected", "input"], ReadBy("fuse", "visibility", keys=("visibility",))
    ] = Field(
        "median",
        description="Depth image for visibility: rendered median or expected depth, or the input depth maps.",
    )
    fusion_backend: Annotated[Literal["auto", "cpu"], ReadBy("fuse", "runtime")] = Field(
        "auto",
        description=(
            "Device of projection, depth test and the fusion state (one torch implementation): "
            "'auto' = the render device (depth stays on the GPU); 'cpu' = the host. The former "
            "'torch' and 'numpy' are read as 'auto' and 'cpu'."
        ),
    )

    @field_validator("fusion_backend", mode="before")
    @classmethod
    def _former_fusion_backends(cls, value: Any) -> Any:
        """Job records and parameter files written before fusion had one implementation name
        its two backends; both now run the same ops, on the render device or on the host."""
        return FORMER_FUSION_BACKENDS.get(value, value) if isinstance(value, str) else value

    scene_scale: Annotated[
        float | None, ReadBy("fuse", "visibility", keys=("visibility", "alignment"), length=True)
    ] = Field(
        None,
        gt=0,
        le=1e9,
        description=(
            "The length every relative length below is a fraction of, in the cameras' (capture) "
            "units. None: derived from the inputs, the median over frames of the median camera "
            "depth of the Gaussian centres in view (scene/scale.py), so the same capture in other "
            "units, rotated or moved gives the same objects. Set it (e.g. 1.0 on a metric capture) "
            "to make the *_scene lengths absolute."
        ),
    )
    depth_tolerance: Annotated[
        float | None, ReadBy("fuse", "visibility", keys=("visibility",), length=True)
    ] = Field(
        None,
        ge=0,
        le=1e6,
        description=(
            "Absolute visibility tolerance on centre depth, in the cameras' (capture) units. "
            "None (default): depth_tolerance_scene x the scene scale. The loader maps a "
            "nerfstudio/gsplat splat into the cameras' frame, so their internal scaling never applies."
        ),
    )
    depth_tolerance_scene: Annotated[
        float, ReadBy("fuse", "visibility", keys=("visibility",), length=True)
    ] = Field(
        0.02704166,
        ge=0,
        le=10,
        description=(
            "Visibility tolerance on centre depth as a fraction of the scene scale (used when "
            "depth_tolerance is None): ~2.7% of the distance the cameras see the scene from. "
            "The value is the former absolute 0.05 over the bundled sample's scale 1.849, so the "
            "sample keeps its results exactly."
        ),
    )
    depth_tolerance_relative: Annotated[float, ReadBy("fuse", "visibility", keys=("visibility",))] = Field(
        0.03,
        ge=0,
        le=10,
        description="Visibility tolerance as a fraction of the rendered depth (added to the absolute one).",
    )

    # --- objects (steps 7-12) --------------------------------------------------------------------
    aib_conditionals: Annotated[Literal["fused", "per_view"], ReadBy("cluster", "objects")] = Field(
        "per_view",
        description=(
            "What the AIB clusters on. 'per_view' (default; departs from the paper): each "
            "primitive's rows from its Gaussians' mean evidence per accepted view, "
            "sigmoid(logit(prior) + (logodds - logit(prior)) / views), which does not grow with "
            "the number of views; the identical pre-merge joins only primitives no accepted view "
            "saw. 'fused' (the paper, to reproduce it): the mean fused probability per task, which "
            "saturates at 1 for every task neighbours share, so their rows stop telling them "
            "apart and the AIB joins them. Rows: null appended, normalised; selection and "
            "pruning use the fused values either way. Docs: Evaluation, merged neighbours."
        ),
    )
    null_mode: Annotated[Literal["product", "one_minus_max"], ReadBy("cluster", "objects")] = Field(
        "product", description="Null task: prod(1-p_y) (default) or 1-max p_y."
    )
    edge_padding: Annotated[float | None, ReadBy("cluster", "objects", length=True)] = Field(
        None,
        ge=0,
        le=1e6,
        description=(
            "Absolute growth of primitive boxes before overlap tests, in capture units. None "
            "(default): edge_padding_scene x the scene scale."
        ),
    )
    edge_padding_scene: Annotated[float, ReadBy("cluster", "objects", length=True)] = Field(
        0.0,
        ge=0,
        le=10,
        description="Growth of primitive boxes before overlap tests, as a fraction of the scene scale.",
    )
    identical_tolerance: Annotated[float, ReadBy("cluster", "objects")] = Field(
        1e-6, ge=0, le=1, description="Max abs difference for 'identical' p(y|x) vectors."
    )
    aib_px: Annotated[Literal["uniform", "size"], ReadBy("cluster", "objects")] = Field(
        "uniform",
        description=(
            "p(x) of the primitives in the AIB: 'uniform' (Clio, METHOD step 9) or 'size' "
            "(proportional to Gaussian count, so a sliver of a few Gaussians weighs little)."
        ),
    )
    aib_delta: Annotated[float, ReadBy("cluster", "objects")] = Field(
        1e-5, gt=0, le=1, description="AIB stops when the relative information loss exceeds this (Clio)."
    )
    prune_threshold: Annotated[float, ReadBy("cluster", "objects")] = Field(
        0.1, ge=0, le=1, description="Drop objects below this probability for every task."
    )
    top_k: Annotated[int, ReadBy("cluster", "objects")] = Field(
        5, ge=1, le=1000, description="Objects kept per task."
    )
    min_object_gaussians: Annotated[int, ReadBy("cluster", "objects")] = Field(
        50,
        ge=1,
        le=100_000_000,
        description=(
            "Objects with fewer Gaussians are never selected: a handful of Gaussians seen through "
            "one relevant mask saturate their probability but are slivers, not objects (ours)."
        ),
    )
    selection_score: Annotated[
        Literal["evidence", "relevance", "conditional"], ReadBy("cluster", "objects")
    ] = Field(
        "evidence",
        description=(
            "Score that ranks a task's objects. 'relevance' = p(y=1|object), the mean fused "
            "probability of its Gaussians (paper Eq. 8); 'evidence' = the mean fused log-odds, "
            "which orders objects alike while they are uncertain and still separates them once "
            "their probabilities saturate at 1; 'conditional' = the normalised p(y|object) the "
            "AIB clusters on, which penalises objects relevant to several tasks at once. Pruning "
            "uses relevance, or the conditional with 'conditional'."
        ),
    )
    answer_min_peak: Annotated[
        Annotated[float, Field(ge=-10, le=10)] | Literal["calibrated"] | None, ReadBy("cluster", "objects")
    ] = Field(
        "calibrated",
        description=(
            "A task whose best object's best single view scores below this margin gets no object "
            "(an empty selection with the reason: 'not found', format 1.3). The margin is "
            "(phi - mu0) / (mu1 - mu0): 0 at the irrelevant mean, 1 at the relevant one. "
            "'calibrated' (default): the threshold `bfields calibrate --scene` fitted for the "
            "encoder (in its calibration file), else the margin a relevant view falls below 2 % "
            "of the time under the calibrated likelihoods. None = always answer. Docs: Not found "
            "answers."
        ),
    )
    knn_filter: Annotated[bool, ReadBy("cluster", "objects")] = Field(
        True, description="Statistical outlier removal on each selected object."
    )
    knn_k: Annotated[int, ReadBy("cluster", "objects")] = Field(
        20, ge=1, le=1000, description="Neighbours for the kNN filter (Open3D default 20)."
    )
    knn_std_ratio: Annotated[float, ReadBy("cluster", "objects")] = Field(
        2.0, gt=0, le=100, description="Keep points with mean kNN distance <= mean + r*std."
    )

    # --- outputs --------------------------------------------------------------------------------
    export_ply: Annotated[bool, ReadBy("cluster", "result files")] = Field(
        True, description="Write one .ply per selected object and a recoloured scene .ply."
    )
    store_primitive_ids: Annotated[bool, ReadBy("cluster", "result files")] = Field(
        True, description="Store per-Gaussian primitive ids in the result."
    )
    previews: Annotated[bool, ReadBy("cluster", "result files")] = Field(
        True, description="Render one preview PNG per task and a contact sheet into the result."
    )
    preview_max_side: Annotated[int, ReadBy("cluster", "result files")] = Field(
        480,
        ge=32,
        le=4096,
        description="Longest side, in pixels, of a preview render (frames are scaled down).",
    )

    # --- execution ------------------------------------------------------------------------------
    device: Annotated[str | None, ReadBy("job", "runtime")] = Field(
        None,
        pattern=r"^(cpu|cuda(:[0-9]{1,2})?|mps)$",
        description=(
            "Torch device for rendering and the models ('cpu', 'cuda', 'cuda:1'). None: the CLI "
            "uses each model's profile device and renders on the CPU; a service worker always uses "
            "its own device (BFIELDS_WORKER_DEVICE) and ignores a job's value."
        ),
    )


def default(name: str) -> Any:
    """The default of one `PipelineParams` field, for a library function's signature.

    Library functions that take a pipeline tunable write `depth_tolerance: float =
    default("depth_tolerance")` instead of a second literal, so the model stays the one place a
    default is written (tests/core/test_params_single_source.py checks it)."""
    try:
        return PipelineParams.model_fields[name].default
    except KeyError:
        raise KeyError(f"PipelineParams has no field {name!r}") from None


def read_by(name: str) -> ReadBy:
    """The `ReadBy` marker of field `name` (every field has exactly one; a test checks it)."""
    try:
        field = PipelineParams.model_fields[name]
    except KeyError:
        raise KeyError(f"PipelineParams has no field {name!r}") from None
    markers = [m for m in field.metadata if isinstance(m, ReadBy)]
    if len(markers) != 1:
        raise TypeError(f"PipelineParams.{name} must carry exactly one ReadBy marker, has {len(markers)}")
    return markers[0]


def readers() -> dict[str, ReadBy]:
    """Every field's `ReadBy`, in declaration order."""
    return {name: read_by(name) for name in PipelineParams.model_fields}


def keyed_parameters(cache: CacheName) -> tuple[str, ...]:
    """The fields whose values enter `cache`'s content key, in declaration order."""
    return tuple(name for name, r in readers().items() if cache in r.keys)


def length_parameters() -> tuple[str, ...]:
    """The fields `scene.scale.scene_lengths` resolves; nothing else reads them."""
    return tuple(name for name, r in readers().items() if r.length)
