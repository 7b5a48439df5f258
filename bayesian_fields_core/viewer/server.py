"""`bfields view`: the result in the browser, on viser (nerfstudio's viewer library).

The splat is drawn as Gaussians by viser's own WebGL splat renderer (the client bundle ships in the
viser wheel, so the page works offline). The GUI panel holds a task selector, the colouring (task
highlight, per-Gaussian relevance heat map, all objects by id, original colours), toggles for boxes
and cameras, the selected task's legend and the clicked object's details. Changing the task only
re-sends colours and boxes; the Gaussians' geometry is sent once.
"""

from __future__ import annotations

import html
import threading
from typing import Any

import numpy as np

from bayesian_fields_core.geometry.transforms import quat_to_rotmat, rotmat_to_quat
from bayesian_fields_core.results.colours import object_palette, rank_colour
from bayesian_fields_core.viewer.data import ViewData
from bayesian_fields_core.viewer.placement import StartView, box_top, label_anchors, label_text, start_view

COLOURINGS = ("task highlight", "relevance heat map", "all objects", "original colours")


def _hex(rgb: np.ndarray) -> str:
    return "#" + "".join(f"{int(round(float(c) * 255)):02x}" for c in rgb)


def _xyz(v: Any) -> tuple[float, float, float]:
    """Three floats, the shape viser's vector arguments are typed with."""
    return (float(v[0]), float(v[1]), float(v[2]))


FLOAT16_MAX = float(np.finfo(np.float16).max)


def _score_text(data: ViewData, obj: Any) -> str:
    """'evidence +12.3' when the ranks follow a score other than p (format 1.4), else ''."""
    if obj.score is None or data.result.ranked_by in ("", "relevance"):
        return ""
    return f"{data.result.ranked_by} {obj.score:+.2f}"


def _unbroken(text: str) -> str:
    """`text` as HTML the panel never breaks inside ("(422 G)" broke before "G"): a legend row
    wraps between its parts only."""
    return '<span style="white-space:nowrap">' + html.escape(text) + "</span>"


def covariances(data: ViewData, unit: float = 1.0) -> np.ndarray:
    """(M, 3, 3) covariances R diag(s^2) R^T of the shown Gaussians, in units of `unit` (so
    divided by unit^2), clipped to the float16 range viser packs them in."""
    rot = quat_to_rotmat(np.asarray(data.gaussians.quats, dtype=np.float64))
    scales = np.exp(np.asarray(data.gaussians.log_scales, dtype=np.float64)) / unit
    cov = np.einsum("nij,nj,nkj->nik", rot, scales**2, rot)
    return np.clip(cov, -FLOAT16_MAX, FLOAT16_MAX).astype(np.float32)


class ResultViewer:
    """One viser server showing one result. `select_task` / `set_colouring` are what the GUI calls;
    `shown_colours` is the (M, 3) colour array last sent for the splat."""

    def __init__(self, data: ViewData, *, host: str = "127.0.0.1", port: int = 8080) -> None:
        import viser

        self.data = data
        self.server = viser.ViserServer(host=host, port=port, label="Bayesian Fields", verbose=False)
        self._lock = threading.Lock()
        self._boxes: list[Any] = []
        self._frustums: list[Any] = []
        self.labels: list[Any] = []
        self.start: StartView | None = None
        self.task = data.tasks[0]
        self.colouring = COLOURINGS[0]
        means = np.asarray(data.gaussians.means, dtype=np.float32)
        self.centre = means.mean(0) if len(means) else np.zeros(3, np.float32)
        self.extent = float(np.linalg.norm(means.max(0) - means.min(0))) if len(means) else 1.0
        self._set_up_direction()
        self.server.scene.set_background_image(np.full((8, 8, 3), 26, dtype=np.uint8))
        self.shown_colours = data.task_colours(self.task)
        # viser sends covariances as float16 (normal range 6e-5 .. 65504): in a scene of a few
        # units that holds millimetre splats, but the same scene in other units (COLMAP's are
        # arbitrary) flushed its small splats to zero at scale 0.01 or overflowed large ones at
        # scale 100. The splat goes over in units of the scene scale, and the node's scale puts
        # it back in the scene's units, where boxes, cameras and click rays are.
        self.splat_unit = data.unit
        self.splats = self.server.scene.add_gaussian_splats(
            "/splat",
            centers=means / np.float32(self.splat_unit),
            covariances=covariances(data, self.splat_unit),
            rgbs=self.shown_colours,
            opacities=np.asarray(data.gaussians.opacities, dtype=np.float32)[:, None],
            scale=self.splat_unit,
        )
        self._build_gui()
        self._add_cameras()
        self._refresh()
        self.server.scene.on_click()(self._on_scene_click)

    # ---- scene -------------------------------------------------------------------------------
    def _set_up_direction(self) -> None:
        """Up = the cameras' mean -y axis (OpenCV), so the scene opens the right way up; the view
        starts at the first training camera (`placement.start_view`)."""
        if not self.data.frames:
            return
        ups = [-np.linalg.inv(f.world_to_camera)[:3, 1] for f in self.data.frames]
        up = np.mean(ups, axis=0)
        if np.linalg.norm(up) > 1e-6:
            self.server.scene.set_up_direction(_xyz(up / np.linalg.norm(up)))
        self.start = start_view(self.data.frames[0], np.asarray(self.data.gaussians.means))
        camera = self.server.initial_camera
        camera.position, camera.look_at = self.start.position, self.start.look_at
        camera.up, camera.fov = self.start.up, self.start.fov
        # viser's clipping planes (0.01 .. 1000) are absolute: follow the scene's units instead
        camera.near, camera.far = 0.01 * self.data.unit, 1000.0 * self.data.unit

    def _add_cameras(self) -> None:
        for i, frame in enumerate(self.data.frames):
            c2w = np.linalg.inv(frame.world_to_camera)
            handle = self.server.scene.add_camera_frustum(
                f"/cameras/{i:04d}",
                fov=float(2 * np.arctan(frame.height / (2 * frame.K[1, 1]))),
                aspect=frame.width / frame.height,
                scale=0.04 * self.extent,
                thickness=0.002 * self.extent,
                color=(200, 200, 210),
                wxyz=tuple(rotmat_to_quat(c2w[:3, :3])),
                position=tuple(c2w[:3, 3]),
                visible=self.gui_cameras.value,
            )
            self._frustums.append(handle)

    def _draw_boxes(self) -> None:
        for handle in self._boxes:
            handle.remove()
        self._boxes = []
        self.labels = []  # children of the boxes: removed with them
        objects = self.data.result.selections.get(self.task, [])
        if not self.gui_boxes.value or not objects:
            return
        texts = [label_text(rank, obj.probability) for rank, obj in enumerate(objects)]
        up = np.asarray(self.start.up) if self.start is not None else np.array([0.0, 0.0, 1.0])
        tops = np.stack([box_top(o.box.center, o.box.rotation, o.box.extents, up) for o in objects])
        anchors = label_anchors(tops, texts, self.data.frames[0]) if self.data.frames else tops
        for rank, (obj, text, anchor) in enumerate(zip(objects, texts, anchors, strict=True)):
            r, g, b = (int(c * 255) for c in rank_colour(rank))
            rotation = np.asarray(obj.box.rotation, dtype=np.float64)
            self._boxes.append(
                self.server.scene.add_box(
                    f"/boxes/{rank}",
                    color=(r, g, b),
                    dimensions=tuple(obj.box.extents),
                    wireframe=True,
                    wxyz=tuple(rotmat_to_quat(rotation)),
                    position=tuple(obj.box.center),
                )  # fmt: skip
            )
            # a child of the box (removed with it), so its anchor goes in the box's own frame
            label = self.server.scene.add_label(
                f"/boxes/{rank}/label",
                text,
                position=_xyz(rotation.T @ (anchor - np.asarray(obj.box.center, dtype=np.float64))),
                anchor="bottom-left",
            )
            self.labels.append(label)

    # ---- GUI ---------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        d = self.data
        gui.add_markdown(
            f"**{d.total_gaussians:,} Gaussians** ({len(d.kept):,} shown), {d.result.num_objects} objects, "
            f"{len(d.tasks)} tasks, {len(d.frames)} cameras"
        )
        self.gui_task = gui.add_dropdown("Task", options=tuple(d.tasks), initial_value=self.task)
        self.gui_colouring = gui.add_dropdown("Colour", options=COLOURINGS, initial_value=self.colouring)
        self.gui_boxes = gui.add_checkbox("Boxes and labels", initial_value=True)
        self.gui_cameras = gui.add_checkbox("Input cameras", initial_value=False)
        self.gui_legend = gui.add_html("")
        # A text field, empty until an object is chosen: a number field showed "-1" for "none".
        self.gui_object = gui.add_text(
            "Object id", initial_value="", hint=f"an id, 0 to {d.result.num_objects - 1}, or click an object"
        )
        self.gui_info = gui.add_html(
            "<p>Click an object in the scene (or type its id) to see its probabilities.</p>"
        )

        @self.gui_task.on_update
        def _(_: Any) -> None:
            self.select_task(self.gui_task.value)

        @self.gui_colouring.on_update
        def _(_: Any) -> None:
            self.set_colouring(self.gui_colouring.value)

        @self.gui_boxes.on_update
        def _(_: Any) -> None:
            self._draw_boxes()

        @self.gui_cameras.on_update
        def _(_: Any) -> None:
            for handle in self._frustums:
                handle.visible = self.gui_cameras.value

        @self.gui_object.on_update
        def _(_: Any) -> None:
            self.show_typed_object(self.gui_object.value)

    def select_task(self, task: str) -> None:
        if task not in self.data.tasks:
            raise ValueError(f"unknown task {task!r}")
        self.task = task
        if self.gui_task.value != task:
            self.gui_task.value = task  # type: ignore[misc]  # viser defines the setter apart from the getter; mypy sees it read-only
        self._refresh()

    def set_colouring(self, colouring: str) -> None:
        if colouring not in COLOURINGS:
            raise ValueError(f"unknown colouring {colouring!r}")
        self.colouring = colouring
        if self.gui_colouring.value != colouring:
            self.gui_colouring.value = colouring  # type: ignore[misc]  # viser defines the setter apart from the getter; mypy sees it read-only
        self._refresh()

    def colours(self) -> np.ndarray:
        d = self.data
        if self.colouring == "task highlight":
            return d.task_colours(self.task)
        if self.colouring == "relevance heat map":
            return d.heat(self.task)
        if self.colouring == "all objects":
            return d.object_colours()
        return d.base

    def _refresh(self) -> None:
        with self._lock:
            self.shown_colours = self.colours()
            self.splats.rgbs = self.shown_colours
            self._draw_boxes()
            self.gui_legend.content = self._legend_html()

    def _legend_html(self) -> str:
        d = self.data
        if self.colouring == "all objects":
            palette = object_palette(d.result.num_objects)
            ids = sorted({o.object_id for objs in d.result.selections.values() for o in objs})
            rows = "".join(
                f'<div><span style="background:{_hex(palette[i])};display:inline-block;width:12px;height:12px"></span>'
                f" object {i}</div>"
                for i in ids
            )
            return f"<p><b>All {d.result.num_objects} objects</b>, one colour each (selected ones listed), grey = none</p>{rows}"
        if self.colouring == "relevance heat map":
            return (
                f"<p><b>{html.escape(self.task)}</b>: p(relevant) per Gaussian ({d.relevance_source}),"
                " dark blue 0 to yellow 1</p>"
            )
        objs = d.result.selections.get(self.task, [])
        rows = "".join(
            f'<div><span style="background:{_hex(rank_colour(r))};display:inline-block;width:12px;height:12px"></span> '
            + " ".join(
                _unbroken(part)
                for part in (
                    f"#{r + 1} object {o.object_id}",
                    _score_text(d, o),
                    f"p={o.probability:.3f}",
                    f"({o.num_gaussians} G)",
                )
                if part
            )
            + "</div>"
            for r, o in enumerate(objs)
        )
        missing = d.result.not_found.get(self.task)
        empty = f"not found: {missing.reason}" if missing else "no object selected"
        return f"<p><b>{html.escape(self.task)}</b></p>{rows or f'<div>{html.escape(empty)}</div>'}"

    def show_typed_object(self, text: str) -> dict[str, Any] | None:
        """Show the object whose id was typed; an empty field shows nothing, anything but an id of
        this result says which ids there are."""
        text = text.strip()
        if not text:
            return None
        last = self.data.result.num_objects - 1
        if not text.isdigit() or int(text) > last:
            self.gui_info.content = f"<p>No object {html.escape(text)}: the ids run 0 to {last}.</p>"
            return None
        return self.show_object(int(text))

    def show_object(self, object_id: int) -> dict[str, Any]:
        info = self.data.object_info(object_id)
        rows = "".join(
            f"<tr><td>{html.escape(t)}</td><td>{v['relevance']:.3f}</td><td>{v['conditional']:.3f}</td></tr>"
            for t, v in info["tasks"].items()
        )
        box = info["box"]
        box_text = (
            "centre (" + ", ".join(f"{c:+.3f}" for c in box["center"]) + "), extents ("
            + ", ".join(f"{c:.3f}" for c in box["extents"]) + ")"
            if box else "no box"
        )  # fmt: skip
        self.gui_info.content = (
            f"<p><b>Object {object_id}</b>: {info['num_gaussians']} Gaussians; {box_text}</p>"
            f"<table><tr><th>task</th><th>p(rel.)</th><th>p(task|obj)</th></tr>{rows}</table>"
        )
        return info

    def _on_scene_click(self, event: Any) -> None:
        object_id = self.data.pick(np.asarray(event.ray_origin), np.asarray(event.ray_direction))
        if object_id is not None:
            self.gui_object.value = str(object_id)  # type: ignore[misc]  # viser defines the setter apart from the getter; mypy sees it read-only
            self.show_object(object_id)

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}"

    def stop(self) -> None:
        self.server.stop()
