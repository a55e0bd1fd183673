"""The Foxglove layout shipped as docs/foxglove-layout.json, built with the SDK's layout
types so that it names the topics of :mod:`rakectl.view.topics` (a test checks the
shipped file is this, as for the configuration reference)."""

from __future__ import annotations

from foxglove.layouts import (
    BaseRendererSceneUpdateTopicSettings,
    Layout,
    PlotConfig,
    PlotPanel,
    PlotSeries,
    RawMessagesConfig,
    RawMessagesPanel,
    SplitContainer,
    SplitItem,
    StateTransitionsConfig,
    StateTransitionsPanel,
    StateTransitionsSeries,
    ThreeDeeCameraState,
    ThreeDeeConfig,
    ThreeDeePanel,
)

from rakectl.view.topics import FRAME


def _plot(title: str, *series: tuple[str, str]) -> PlotPanel:
    return PlotPanel(title=title, config=PlotConfig(
        show_legend=True, paths=[PlotSeries(value=value, label=label, enabled=True)
                                 for value, label in series]))


def build() -> str:
    """The layout as JSON: the rake and the ground seen from the side, the forces next to
    the clamp's budget and the limit, the voltages, the states, the loop's timing."""
    scene = ThreeDeePanel(title="rake and ground (side view)", config=ThreeDeeConfig(
        follow_tf=FRAME,
        topics={"/rake": BaseRendererSceneUpdateTopicSettings(visible=True),
                "/ground": BaseRendererSceneUpdateTopicSettings(visible=True)},
        # looking along y at the vertical plane: reach to the right, height up
        camera_state=ThreeDeeCameraState(distance=2.5, perspective=False, phi=90.0,
                                         theta_offset=0.0, target=(1.0, 0.0, 0.1))))
    forces = _plot("force on the ground (N)",
                   ("/force.f_hat_n", "F̂ (estimated)"),
                   ("/force.f_current_n", "from the currents"),
                   ("/truth.force_down_n", "true (emulated bench)"),
                   ("/force.clamp_worst_case_n", "clamp: worst case"),
                   ("/force.clamp_budget_n", "clamp: budget"),
                   ("/force.clamp_limit_n", "clamp: limit"))
    voltages = _plot("voltages (V): asked and after the clamp",
                     ("/voltage.requested_r_v", "r asked"),
                     ("/voltage.applied_r_v", "r sent"),
                     ("/voltage.requested_theta_v", "θ asked"),
                     ("/voltage.applied_theta_v", "θ sent"))
    states = StateTransitionsPanel(title="state and supervision", config=StateTransitionsConfig(
        paths=[StateTransitionsSeries(value="/state.state", label="state"),
               StateTransitionsSeries(value="/state.level", label="force level"),
               StateTransitionsSeries(value="/state.phase", label="excavation")]))
    timing = _plot("loop wake-up latency (µs)", ("/timing.latency_p99_us", "p99"),
                   ("/timing.latency_max_us", "max"))
    raw = RawMessagesPanel(title="state", config=RawMessagesConfig(topic_path="/state"))
    content = SplitContainer(direction="row", items=[
        SplitItem(proportion=1.2, content=SplitContainer(direction="column", items=[
            SplitItem(proportion=2, content=scene), SplitItem(content=states),
            SplitItem(proportion=0.6, content=raw)])),
        SplitItem(proportion=1, content=SplitContainer(direction="column", items=[
            SplitItem(proportion=2, content=forces), SplitItem(content=voltages),
            SplitItem(content=timing)]))])
    return Layout(content=content).to_json()
