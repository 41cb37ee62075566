"""One meaning per name: the stage parameters, stage type and port renamed so that ``frames`` means
time codes, ``samples`` rays per vertex and ``model`` the fitted artifact port only. A graph that
still uses an old name is refused, before any work, with the new name in the error
(``warpshade.methods.stage.RENAMED_PARAMS`` / ``RENAMED_TYPES``, ``warpshade.graph._spec.RENAMED_PORTS``)."""

import re
from pathlib import Path

import pytest

import warpshade.methods  # noqa: F401  (registers the stage types)
from warpshade.graph import GraphError, GraphSpec, StageError, StageSpec, get_stage_type, load, stage_types
from warpshade.graph._spec import RENAMED_PORTS
from warpshade.methods.stage import RENAMED_PARAMS, RENAMED_TYPES

STAGES = Path(__file__).resolve().parents[1] / "stages"

#: The renames, written out: the tables must say exactly this.
PARAMS = {("datadriven.fit", "model"): "reduction", ("visibility.fit", "model"): "regressor",
          ("visibility.fit", "frames"): "space", ("shexp.tables", "samples"): "quadrature"}


def test_the_tables_hold_the_renames():
    assert RENAMED_PARAMS == PARAMS
    assert RENAMED_TYPES == {"ldprt.frames": "ldprt.tangents"}
    assert RENAMED_PORTS == {"frames": "tangents"}


@pytest.mark.parametrize("type_name, old", sorted(PARAMS))
def test_a_renamed_parameter_is_gone_and_its_new_name_is_known(type_name, old):
    cls = get_stage_type(type_name)
    assert old not in cls.parameters and PARAMS[(type_name, old)] in cls.parameters
    assert old not in cls.quick


@pytest.mark.parametrize("type_name, old", sorted(PARAMS))
def test_an_old_parameter_name_says_what_it_was_renamed(type_name, old):
    new = PARAMS[(type_name, old)]
    value = get_stage_type(type_name).parameters[new].default
    with pytest.raises(StageError, match=rf"unknown parameter\(s\) \['{old}'\].*; '{old}' was renamed '{new}'"):
        get_stage_type(type_name)("s", {old: value})
    # in a graph: refused at check, naming the stage
    spec = GraphSpec([StageSpec("s", type_name, {old: value})], "s.radiance", name="old")
    with pytest.raises(GraphError, match=rf"stage 's' \({re.escape(type_name)}\).*'{old}' was renamed '{new}'"):
        spec.check()


def test_every_old_name_of_one_stage_is_named():
    with pytest.raises(StageError, match=r"'frames' was renamed 'space'; 'model' was renamed 'regressor'"):
        get_stage_type("visibility.fit")("fit", {"model": "auto", "frames": "cluster"})


def test_an_unknown_parameter_that_was_not_renamed_gets_no_hint():
    with pytest.raises(StageError, match=r"unknown parameter\(s\) \['model'\]") as err:
        get_stage_type("ldprt.fit")("fit", {"model": "x"})
    assert "renamed" not in str(err.value)


def test_the_old_stage_type_says_what_it_was_renamed():
    assert "ldprt.frames" not in stage_types() and "ldprt.tangents" in stage_types()
    with pytest.raises(StageError, match=r"stage 'frames': unknown stage type 'ldprt.frames' "
                                         r"\('ldprt.frames' was renamed 'ldprt.tangents'\)"):
        get_stage_type("ldprt.frames", "frames")
    with pytest.raises(StageError) as err:
        get_stage_type("ldprt.nothing", "x")
    assert "renamed" not in str(err.value)


def _ldprt(tangents_stage=("tangents", "ldprt.tangents"), inputs=None):
    name, type_name = tangents_stage
    return GraphSpec([StageSpec("fit", "ldprt.fit", {"order": 3}), StageSpec(name, type_name),
                      StageSpec("shade", "ldprt.shade", {"order": 3}, inputs or {})], "shade.radiance", name="old")


def test_the_new_graph_checks():
    _ldprt().check()
    _ldprt(inputs={"tangents": "tangents.tangents"}).check()


def test_a_wire_to_the_old_output_port_names_the_port_and_the_new_name():
    with pytest.raises(GraphError, match=r"stage 'shade' input 'tangents': 'tangents' has no output 'frames' "
                                         r"\(outputs: \['tangents'\]\); port 'frames' was renamed 'tangents'"):
        _ldprt(inputs={"tangents": "tangents.frames"}).check()


def test_a_wire_into_the_old_input_port_names_the_port_and_the_new_name():
    with pytest.raises(GraphError, match=r"stage 'shade' has no input port 'frames' \(inputs: .*\); "
                                         r"port 'frames' was renamed 'tangents'"):
        _ldprt(inputs={"frames": "tangents.tangents"}).check()


def test_a_wrong_port_that_was_not_renamed_gets_no_hint():
    with pytest.raises(GraphError, match=r"has no output 'normals'") as err:
        _ldprt(inputs={"tangents": "tangents.normals"}).check()
    assert "renamed" not in str(err.value)


def _old(tmp_path, graph: str, *renames) -> GraphSpec:
    """``stages/<graph>.toml`` written back with the old names (``(new, old)`` text replacements),
    loaded (loading checks the graph already)."""
    text = (STAGES / f"{graph}.toml").read_text()
    for new, old in renames:
        assert new in text
        text = text.replace(new, old)
    path = tmp_path / f"{graph}.toml"
    path.write_text(text)
    return load(path)


def test_an_old_ldprt_graph_file_is_told_the_new_names(tmp_path):
    old_type = ('type = "ldprt.tangents"', 'type = "ldprt.frames"')
    old_wires = ('tangents = "tangents.tangents"', 'frames = "frames.frames"')
    old_name = ('name = "tangents"', 'name = "frames"')
    with pytest.raises((GraphError, StageError), match=r"'ldprt.frames' was renamed 'ldprt.tangents'"):
        _old(tmp_path, "cloth_hybrid", old_type, old_wires, old_name).check()
    # the type renamed, the stage name and the wires not yet
    with pytest.raises(GraphError, match=r"port 'frames' was renamed 'tangents'"):
        _old(tmp_path, "cloth_hybrid", old_wires, old_name).check()


@pytest.mark.parametrize("graph, new, old", [("figure_datadriven", "reduction", "model"),
                                             ("figure_visibility", "regressor", "model")])
def test_an_old_fit_graph_file_is_told_the_new_parameter_name(tmp_path, graph, new, old):
    with pytest.raises((GraphError, StageError), match=rf"'{old}' was renamed '{new}'"):
        _old(tmp_path, graph, (f"\n{new} = ", f"\n{old} = ")).check()


def _ports_of_defaults():
    """(type, stage) of every stage type that builds with its default parameters, plus the
    variants whose ports depend on a parameter (hybrid: local frame, reprojection)."""
    out = []
    for name, cls in sorted(stage_types().items()):
        try:
            out.append((name, cls("s")))
        except (StageError, ValueError, TypeError):
            pass
    out.append(("hybrid.trace local", get_stage_type("hybrid.trace")("s", {"space": "local"})))
    out.append(("hybrid.trace reproject", get_stage_type("hybrid.trace")("s", {"reproject": True})))
    return out


def test_no_stage_has_a_port_named_frames():
    """``frames`` means time codes only: the per-vertex tangent frames travel on ``tangents``."""
    stages = _ports_of_defaults()
    assert any(name == "ldprt.tangents" for name, _ in stages)
    for name, st in stages:
        ports = {**st.input_ports(), **st.output_ports()}
        assert "frames" not in ports, name
        for port_name, port in ports.items():
            if port.dtype == "mat33":
                assert port_name == "tangents", (name, port_name)
