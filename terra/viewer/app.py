"""The viser application of `terra view`: scene layers, GUI controls, and the queries they run.

The server listens on `host:port` (loopback by default). Points are drawn from a fixed subset
(scene.display_subset); places, each region level and the objects are layers with toggles; the
query box runs find or monitor and highlights the answer; start and goal (typed, or picked on the
map) run a terrain-aware plan whose path and per-terrain lengths are shown; a map of several sessions
gets a Changes folder (terra/viewer/changes.py). Queries run through the
typed task API (terra.tasks.commands) on the shared LoadedBundle, from viser's worker threads.
"""

from __future__ import annotations

import errno
import socket
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from terra.errors import TerraError
from terra.viewer import scene

if TYPE_CHECKING:
    from terra.graph.scene_graph import SceneGraph
    from terra.loaded import LoadedBundle
    from terra.tasks.config import TasksConfig

COLOUR_MODES = ("terrain", "MS-Max class", "similarity")
HIGHLIGHT = (255, 127, 14)
PATH_COLOUR = (0, 188, 212)


def free_port(host: str) -> int:
    """A port the OS says is free on `host` now (for suggestions and tests)."""
    with socket.socket(_family(host), socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _family(host: str) -> int:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def check_port(host: str, port: int) -> None:
    """TerraError (one line) unless `host:port` can be listened on; a busy port names another."""
    if not 1 <= int(port) <= 65535:
        raise TerraError(f"--port must be between 1 and 65535, got {port}")
    try:
        family = _family(host)
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.bind((host, int(port)))
    except socket.gaierror:
        raise TerraError(f"--host {host!r}: not an address of this machine") from None
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise TerraError(f"port {port} on {host} is in use; try --port {free_port(host)}") from None
        raise TerraError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None


class TerraViewer:
    """A running viewer of one LoadedBundle. `max_points` bounds the points drawn (not used)."""

    def __init__(
        self,
        loaded: LoadedBundle,
        host: str = "127.0.0.1",
        port: int = 8080,
        max_points: int = 200_000,
        config: TasksConfig | None = None,
    ):
        from terra.tasks.config import TasksConfig

        self.loaded = loaded
        self.config = config or TasksConfig()
        self.msm = loaded.require_map("terra view")
        self.graph = loaded.graph
        self.version = loaded.bundle.version  # the bundle version drawn (refresh() follows newer ones)
        self.max_points = max_points
        self.rows = scene.display_subset(len(self.msm), max_points)
        self.last_result: Any = None
        self._picking: str | None = None
        self._lock = threading.Lock()  # one query at a time updates the scene
        check_port(host, port)
        import viser

        self.server = viser.ViserServer(host=host, port=port, label="Terra", verbose=False)
        if self.server.get_port() != port:  # viser moves to the next port when one is taken
            taken = self.server.get_port()
            self.server.stop()
            raise TerraError(f"port {port} on {host} is in use; try --port {taken}")
        try:
            self._build()
        except BaseException:
            self.server.stop()
            raise

    def _point_size(self) -> float:
        """Drawn point size (metres): most of a map voxel, more when the drawing is thinned."""
        thinning = (len(self.msm) / max(len(self.rows), 1)) ** (1 / 3)
        return float(np.clip(0.6 * self.msm.voxel_size * thinning, 0.05, 2.0))

    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'[' + host + ']' if ':' in host else host}:{self.server.get_port()}"

    def stop(self) -> None:
        self.server.stop()

    # ------------------------------------------------------------------ scene

    def _build(self) -> None:
        self.server.scene.set_up_direction("+z")
        self.points = self.server.scene.add_point_cloud(
            "/map/points",
            self.msm.points[self.rows],
            scene.terrain_point_colours(self.msm, self.rows),
            point_size=self._point_size(),
            precision="float32",
            point_shape="square",
        )
        self.layers: dict[str, list] = {}
        self._draw_trajectory()
        if self.graph is not None:
            self.layers = self._graph_layers(self.graph)
        self._gui_points()
        self._gui_layers()
        self._gui_ask()
        if self.graph is not None:
            self._gui_plan(self.graph)
        self._gui_changes()
        self._set_camera()

    def refresh(self) -> bool:
        """Draw the bundle's newest version if another process committed one (`terra view --live`):
        points, trajectory and graph layers are replaced in the open page, no reload; the queries
        then answer on that version. Returns whether the version changed."""
        from terra.bundle import Bundle
        from terra.loaded import LoadedBundle

        if Bundle(self.loaded.path).version == self.version:
            return False
        loaded = LoadedBundle(self.loaded.path, embedder=self.loaded._embedder)
        msm, graph = loaded.require_map("terra view"), loaded.graph
        with self._lock:
            self.loaded, self.msm, self.graph, self.version = loaded, msm, graph, loaded.bundle.version
            self.rows = scene.display_subset(len(msm), self.max_points)
            self.points.points = msm.points[self.rows]
            self.recolour()
            self._draw_trajectory()
            self._replace_graph_layers(graph)
            self.header.content = self._header()
        return True

    def _replace_graph_layers(self, graph: SceneGraph | None) -> None:
        """New graph layers in place of the old, the layer toggles keeping their handles' lists."""
        for handles in self.layers.values():  # first: a new node of the same name would replace it
            for handle in handles:
                handle.remove()
        fresh = self._graph_layers(graph) if graph is not None else {}
        for name, handles in self.layers.items():
            handles[:] = fresh.pop(name, [])
        first_graph = not self.layers and bool(fresh)
        self.layers.update(fresh)
        if first_graph and graph is not None:  # the graph appeared: its controls too
            self._gui_layers()
            self._gui_plan(graph)

    def _draw_trajectory(self) -> None:
        """The drive so far: camera positions in stamp order, as a line."""
        segments = scene.trajectory_segments(self.msm)
        if len(segments):
            self.server.scene.add_line_segments(
                "/map/trajectory", segments, (20, 20, 20), thickness=3.0, thickness_units="screen"
            )

    def _graph_layers(self, graph: SceneGraph) -> dict[str, list]:
        lifted = (graph.places.position + np.array([0.0, 0.0, 1.0])).astype(np.float32)
        layers: dict[str, list] = {
            "places": [
                self.server.scene.add_point_cloud(
                    "/graph/places",
                    lifted,
                    scene.place_colours(graph),
                    point_size=1.6,
                    point_shape="circle",
                    precision="float32",
                ),
                self.server.scene.add_line_segments(
                    "/graph/place_edges",
                    scene.place_edge_segments(graph, lift=1.0),
                    (60, 60, 60),
                    thickness=2.5,
                    thickness_units="screen",
                ),
            ]
        }
        for layer in scene.region_layers(graph):
            layers[f"regions level {layer.level}"] = [
                self.server.scene.add_point_cloud(
                    f"/graph/regions_{layer.level}/nodes",
                    layer.position.astype(np.float32),
                    layer.colours,
                    point_size=2.5,
                    point_shape="circle",
                    precision="float32",
                    visible=False,
                ),
                self.server.scene.add_line_segments(
                    f"/graph/regions_{layer.level}/children",
                    layer.segments,
                    layer.segment_colours,
                    thickness=1.5,
                    thickness_units="screen",
                    visible=False,
                ),
            ]
        layers["objects"] = self._draw_objects(
            "/graph/objects",
            graph.objects.center,
            graph.objects.size,
            graph.objects.yaw,
            [f"{lb}" for lb in graph.objects.label],
            (230, 60, 200),
        )
        return layers

    def _draw_objects(self, prefix: str, center, size, yaw, labels: list[str], colour) -> list:
        handles = []
        for i, (c, s, y, text) in enumerate(zip(center, size, yaw, labels)):
            handles.append(
                self.server.scene.add_box(
                    f"{prefix}/{i}/box",
                    colour,
                    _xyz(s),
                    wireframe=True,
                    wxyz=scene.yaw_wxyz(float(y)),
                    position=_xyz(c),
                )
            )
            handles.append(
                self.server.scene.add_label(f"{prefix}/{i}/label", text, position=_xyz(c + [0, 0, s[2] / 2 + 0.5]))
            )
        return handles

    def _set_camera(self) -> None:
        from terra.viz.render import mapped_extent

        x0, x1, y0, y1 = mapped_extent(self.msm, self.graph)
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, float(np.median(self.msm.points[self.rows, 2]))])
        span = max(x1 - x0, y1 - y0)
        self.server.initial_camera.position = tuple(centre + np.array([0.0, -0.4 * span, 0.55 * span]))
        self.server.initial_camera.look_at = tuple(centre)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)

    # ------------------------------------------------------------------ GUI

    def _gui_points(self) -> None:
        gui = self.server.gui
        self.header = gui.add_markdown(self._header())
        with gui.add_folder("Points"):
            self.colour_mode = gui.add_dropdown("colour by", COLOUR_MODES, initial_value="terrain")
            self.similarity_text = gui.add_text("similar to", "")
            self.point_size = gui.add_slider("point size", 0.05, 2.0, 0.05, self._point_size())
            self.legend = gui.add_html(self._terrain_legend())
        self.colour_mode.on_update(lambda _: self._guarded(self.recolour, self.legend))
        self.similarity_text.on_update(
            lambda _: self._guarded(self.recolour, self.legend) if self.colour_mode.value == "similarity" else None
        )
        self.point_size.on_update(lambda _: setattr(self.points, "point_size", float(self.point_size.value)))

    def _header(self) -> str:
        return (
            f"**Terra** · `{self.loaded.path.name}` · version {self.version} · {len(self.msm):,} points"
            f" ({len(self.rows):,} drawn)" + (f" · {len(self.graph.places)} places" if self.graph is not None else "")
        )

    def _gui_layers(self) -> None:
        if self.graph is None:
            return
        with self.server.gui.add_folder("Layers"):
            for name, handles in self.layers.items():
                box = self.server.gui.add_checkbox(name, initial_value=name in ("places", "objects"))
                box.on_update(_visibility_toggle(handles))

    def _gui_ask(self) -> None:
        gui = self.server.gui
        with gui.add_folder("Ask"):
            self.task = gui.add_dropdown(
                "task", ("find", "monitor") if self.graph is not None else ("find",), initial_value="find"
            )
            self.query = gui.add_text("query", "")
            self.ask_button = gui.add_button("Run query")
            self.answer = gui.add_markdown("Type a query, e.g. *find the dumpster*, and run it.")
        self.ask_button.on_click(
            lambda _: self._guarded(lambda: self.run_query(self.task.value, self.query.value), self.answer)
        )

    def _gui_plan(self, graph: SceneGraph) -> None:
        gui = self.server.gui
        with gui.add_folder("Plan"):
            self.start = gui.add_text("start", "", hint="place id, a query, or empty for the first camera pose")
            self.goal = gui.add_text("goal", "", hint="place id or a query, e.g. get bike from the bicycle rack")
            pick_start, pick_goal = gui.add_button("Pick start on map"), gui.add_button("Pick goal on map")
            self.prefer = gui.add_text("prefer", "", hint="terrains, comma-separated")
            self.forbid = gui.add_text("forbid", "", hint="terrains, comma-separated")
            self.plan_button = gui.add_button("Plan")
            self.plan_answer = gui.add_markdown(f"Terrains: {', '.join(graph.terrain_classes)}")
        pick_start.on_click(lambda _: self._pick("start"))
        pick_goal.on_click(lambda _: self._pick("goal"))
        self.plan_button.on_click(
            lambda _: self._guarded(
                lambda: self.run_plan(self.start.value, self.goal.value, self.prefer.value, self.forbid.value),
                self.plan_answer,
            )
        )

    def _gui_changes(self) -> None:
        """A Changes folder when the map holds two sessions or more (terra map --into)."""
        from terra.mapping.sessions import session_list

        info = self.loaded.bundle.model.components.map
        sessions = [str(s["session"]) for s in session_list(list(info.sources or []) if info else [])]
        if len(sessions) < 2:
            return
        gui = self.server.gui
        with gui.add_folder("Changes", expand_by_default=False):
            first = gui.add_dropdown("from session", sessions, initial_value=sessions[-2])
            second = gui.add_dropdown("to session", sessions, initial_value=sessions[-1])
            button = gui.add_button("Show changes")
            answer = gui.add_markdown("Objects added, removed and moved, and terrain that changed class.")
        button.on_click(lambda _: self._guarded(lambda: self.run_changes(int(first.value), int(second.value)), answer))

    def run_changes(self, first: int, second: int) -> str:
        """Draw what changed from session `first` to `second` (terra changes) and return its summary."""
        from terra.tasks.change_report import report_changes
        from terra.viewer.changes import KIND_COLOURS, change_markers, changes_markdown

        self._clear("/results/changes")
        result = report_changes(self.loaded.path, first, second)
        self.last_result = result
        markers = change_markers(result, self.msm.points[self.rows])
        for kind, centres in markers.objects.items():
            for i, centre in enumerate(centres):
                self.server.scene.add_icosphere(
                    f"/results/changes/{kind}/{i}", radius=0.8, color=KIND_COLOURS[kind], position=_xyz(centre)
                )
        if len(markers.moves):
            self.server.scene.add_line_segments(
                "/results/changes/moves", markers.moves, KIND_COLOURS["moved"], thickness=5.0, thickness_units="screen"
            )
        if len(markers.cells):
            self.server.scene.add_point_cloud(
                "/results/changes/terrain",
                markers.cells.astype(np.float32),
                markers.cell_colours,
                point_size=float(np.sqrt(result.terrain_cell_area)),
                point_shape="square",
                precision="float32",
            )
        return changes_markdown(result)

    def _pick(self, which: str) -> None:
        """The next click on the map sets `which` to the nearest place."""
        graph = self.graph
        if graph is None:  # the plan controls that pick exist only with a graph
            return
        self._picking = which

        @self.server.scene.on_pointer_event("click")
        def _clicked(event) -> None:
            self.server.scene.remove_pointer_callback()
            place = scene.ray_place(graph, np.asarray(event.ray_origin), np.asarray(event.ray_direction))
            if place >= 0:
                (self.start if self._picking == "start" else self.goal).value = str(place)
            self._picking = None

    def _guarded(self, action, target) -> None:
        """Run a GUI action, one at a time, and show its text (if any) in the GUI element
        `target`; a user error is shown there too, not raised into viser's thread."""
        try:
            with self._lock:
                text = action()
        except TerraError as exc:
            text = f"**Error:** {_escape(str(exc))}"
        if text is not None:
            target.content = text

    def _terrain_legend(self) -> str:
        from terra.viz.style import terrain_palette

        rows = scene.to_uint8(terrain_palette(self.msm.terrain_classes))
        names = list(self.msm.terrain_classes) + ["not terrain"]
        return _legend_html(names, rows)

    # ------------------------------------------------------------------ colours

    def recolour(self) -> None:
        """Colour the drawn points by the selected mode."""
        from terra.tasks.commands import point_scorer

        mode = self.colour_mode.value
        if mode == "terrain":
            self.points.colors = scene.terrain_point_colours(self.msm, self.rows)
            self.legend.content = self._terrain_legend()
        elif mode == "MS-Max class":
            names, class_of_bank = self._bank_classes()
            palette = scene.class_palette(len(names))
            max_ids = point_scorer(self.loaded).max_ids[self.rows]
            self.points.colors = scene.class_point_colours(max_ids, class_of_bank, palette)
            shown = np.unique(class_of_bank[max_ids[max_ids >= 0]])
            self.legend.content = _legend_html(
                [names[i] for i in shown] + ["unobserved"], np.vstack([palette[shown], scene.UNOBSERVED])
            )
        else:
            text = self.similarity_text.value.strip()
            if not text:
                self.legend.content = "Type a text in <i>similar to</i>."
                return
            vector = self.loaded.embedder.embed_text([text])
            sim = point_scorer(self.loaded).similarity(vector, "avg", rows=self.rows)[:, 0]
            colours, (lo, hi) = scene.similarity_colours(sim, point_scorer(self.loaded).max_ids[self.rows] >= 0)
            self.points.colors = colours
            self.legend.content = f"cosine to “{_escape(text)}”: {lo:.2f} (dark) … {hi:.2f} (yellow); grey: unobserved"

    def _bank_classes(self) -> tuple[list[str], np.ndarray]:
        """Names for the MS-Max colours: the dataset's class names nearest each bank entry, or
        the bank entries themselves when the map lists no classes."""
        meta = self.loaded.bundle.json("map/meta.json") if self.loaded.bundle.has("map/meta.json") else {}
        names = [str(c["name"]) for c in meta.get("classes", []) if isinstance(c, dict) and c.get("name")]
        if not names:
            return [f"bank entry {k}" for k in range(self.msm.bank.shape[0])], np.arange(self.msm.bank.shape[0])
        return names, scene.bank_classes(self.msm.bank, self.loaded.embedder.embed_text(names))

    # ------------------------------------------------------------------ queries

    def run_query(self, task: str, text: str) -> str:
        """Run find or monitor for `text`, highlight the answer, return its summary (Markdown)."""
        from terra.tasks.commands import find, monitor
        from terra.tasks.requests import FindRequest, MonitorRequest

        self._clear("/results/query")
        if task == "find":
            result = find(self.loaded, FindRequest(queries=[text]), self.config)
            self.last_result = result
            objects = result.objects
            self._draw_objects(
                "/results/query/objects",
                [o.center for o in objects],
                [o.size for o in objects],
                [o.yaw for o in objects],
                [f"{o.label} {o.score:.2f}" for o in objects],
                HIGHLIGHT,
            )
            lines = [f"**{len(objects)} objects** for “{_escape(text)}” ({result.method}, alpha {result.alpha:.2f})"]
            lines += [
                f"- {o.score:.2f} at ({o.center[0]:.1f}, {o.center[1]:.1f}) m, place {o.place}" for o in objects[:8]
            ]
            return "\n".join(lines)
        result = monitor(self.loaded, MonitorRequest(queries=[text]), self.config)
        self.last_result = result
        answer = result.results[0]
        places = np.asarray(answer.places, dtype=np.int64)
        if places.size:
            pos = (result.graph.places.position[places] + np.array([0.0, 0.0, 0.6])).astype(np.float32)
            self.server.scene.add_point_cloud(
                "/results/query/places", pos, HIGHLIGHT, point_size=2.0, point_shape="circle", precision="float32"
            )
        regions = ", ".join(f"L{lv}#{ix} {s:.2f}" for (lv, ix), s in zip(answer.regions, answer.region_scores))
        head = f"**{places.size} places** to monitor for “{_escape(text)}” ({result.method}, k {result.k})"
        return f"{head}; regions: {regions or 'none'}"

    def run_plan(self, start: str, goal: str, prefer: str = "", forbid: str = "") -> str:
        """Plan from `start` to `goal` (place ids or queries), draw the path, return its summary."""
        from terra.errors import NoPathError
        from terra.tasks.commands import plan
        from terra.tasks.requests import PlanRequest

        self._clear("/results/plan")
        kind_goal, goal_value = scene.parse_end(goal)
        kind_start, start_value = scene.parse_end(start)
        if kind_goal == "default":
            raise TerraError("give a goal: a place id or a query")
        values: dict[str, Any] = {
            "to" if kind_goal == "query" else "to_node": goal_value,
            "prefer": scene.terrain_list(prefer),
            "forbid": scene.terrain_list(forbid),
        }
        if kind_start != "default":
            values["from" if kind_start == "query" else "from_node"] = start_value
        try:
            result = plan(self.loaded, PlanRequest.model_validate(values), self.config)
        except NoPathError as exc:
            return f"**No path:** {exc}"
        self.last_result = result
        graph = self.loaded.require_graph("terra plan")  # plan() has loaded it
        path = result.plan
        self.server.scene.add_line_segments(
            "/results/plan/path",
            scene.path_segments(path.waypoints),
            PATH_COLOUR,
            thickness=6.0,
            thickness_units="screen",
        )
        for name, place, colour in (("start", path.start, (227, 26, 28)), ("goal", path.goal, (0, 0, 0))):
            self.server.scene.add_icosphere(
                f"/results/plan/{name}",
                radius=1.2,
                color=colour,
                position=_xyz(graph.places.position[place] + [0, 0, 0.6]),
            )
        shares = ", ".join(f"{k} {v:.1f} m" for k, v in path.length_by_terrain.items())
        return f"**Path** {path.length_m:.1f} m over {len(path.places)} places ({shares}); cost {path.cost:.1f}"

    def _clear(self, prefix: str) -> None:
        self.server.scene.add_frame(prefix, show_axes=False)  # replacing a node drops its children


def _xyz(v: np.ndarray) -> tuple[float, float, float]:
    """A 3-vector as the float triple viser takes."""
    return (float(v[0]), float(v[1]), float(v[2]))


def _visibility_toggle(handles: list) -> Callable[[Any], None]:
    """A checkbox callback showing or hiding every scene handle of one layer."""

    def toggle(event: Any) -> None:
        for h in handles:
            h.visible = bool(event.target.value)

    return toggle


def _escape(text: str) -> str:
    import html

    return html.escape(text)


def _legend_html(names: list[str], colours: np.ndarray) -> str:
    items = "".join(
        '<span style="display:inline-block;margin:1px 6px 1px 0">'
        f'<span style="display:inline-block;width:10px;height:10px;'
        f'background:rgb({c[0]},{c[1]},{c[2]});margin-right:3px"></span>{_escape(n)}</span>'
        for n, c in zip(names, colours)
    )
    return f'<div style="font-size:12px;line-height:1.4">{items}</div>'
