"""The declared dataflow (deploy/dataflow.yaml): which node reads and writes which key.

    flow = dataflow.load()
    flow.publishers(keys.SETPOINT)         # ('planner',)
    problems = flow.check(["source", "detector", "smoother", "planner", "autopilot_bridge"])

One file, read here and nowhere else; the topic table (shared/keys.py) says what a key carries,
this says who talks over it. Access rules, the deploy check, the generated docs and the monitor
all derive from it.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import yaml

from cinetransfer.shared import keys

PATH = Path(__file__).resolve().parents[1] / "deploy" / "dataflow.yaml"


class DataflowError(ValueError):
    """The dataflow file is malformed or names an unknown key."""


@dataclass(frozen=True)
class NodeDecl:
    name: str
    module: str
    command: str
    doc: str
    inputs: tuple[keys.Topic, ...]
    outputs: tuple[keys.Topic, ...]
    external: bool = False  # a tool outside the deployment (operator, observer)


def topic_by_path(path: str) -> keys.Topic:
    """`service/topic` -> the topic-table entry (DataflowError naming the key if unknown)."""
    for t in keys.TOPICS:
        if f"{t.service}/{t.topic}" == path:
            return t
    known = ", ".join(f"{t.service}/{t.topic}" for t in keys.TOPICS)
    raise DataflowError(f"unknown key {path!r} (the topic table has: {known})")


def key_path(t: keys.Topic) -> str:
    return f"{t.service}/{t.topic}"


@dataclass(frozen=True)
class Dataflow:
    nodes: dict[str, NodeDecl]
    exclusive: frozenset[keys.Topic]

    def publishers(self, topic: keys.Topic, *, external: bool = True) -> tuple[str, ...]:
        return tuple(n.name for n in self.nodes.values() if topic in n.outputs and (external or not n.external))

    def subscribers(self, topic: keys.Topic) -> tuple[str, ...]:
        return tuple(n.name for n in self.nodes.values() if topic in n.inputs)

    def check(self, deployed: list[str] | dict[str, str]) -> list[str]:
        """Problems of a deployment (empty = fine): its processes as node names, or as a mapping
        process name -> node name (its role). External tools (operator, observer) are taken to be
        present."""
        procs = deployed if isinstance(deployed, dict) else {n: n for n in deployed}
        problems = [f"node {r!r} is not declared in {PATH.name} (declared: {', '.join(self.nodes)})"
                    for r in procs.values() if r not in self.nodes]
        present = [self.nodes[r] for r in procs.values() if r in self.nodes]
        present += [n for n in self.nodes.values() if n.external]
        for node in present:
            if node.external:
                continue
            for t in node.inputs:
                if not any(t in p.outputs for p in present):
                    problems.append(f"{node.name} reads {key_path(t)} but no node of the deployment writes it")
        for t in sorted(self.exclusive, key=key_path):
            writers = [p for p, r in procs.items() if r in self.nodes and t in self.nodes[r].outputs]
            if len(writers) > 1:
                problems.append(f"{key_path(t)} has {len(writers)} writers ({', '.join(writers)}); only one may")
        return list(dict.fromkeys(problems))


def parse(doc: object) -> Dataflow:
    if not isinstance(doc, dict) or not isinstance(doc.get("nodes"), dict):
        raise DataflowError(f"{PATH}: expected a mapping with 'nodes'")
    nodes = {}
    for name, d in doc["nodes"].items():
        if not isinstance(d, dict):
            raise DataflowError(f"{PATH}: node {name!r} must be a mapping")
        try:
            nodes[name] = NodeDecl(name=str(name), module=str(d["module"]), command=str(d["command"]),
                                   doc=str(d.get("doc", "")), external=bool(d.get("external", False)),
                                   inputs=tuple(topic_by_path(p) for p in d.get("inputs", [])),
                                   outputs=tuple(topic_by_path(p) for p in d.get("outputs", [])))
        except KeyError as e:
            raise DataflowError(f"{PATH}: node {name!r} lacks {e.args[0]!r}") from None
    exclusive = frozenset(topic_by_path(p) for p in doc.get("exclusive", []))
    return Dataflow(nodes, exclusive)


@functools.lru_cache(maxsize=1)
def load() -> Dataflow:
    """The declared dataflow (read once)."""
    return parse(yaml.safe_load(PATH.read_text()))
