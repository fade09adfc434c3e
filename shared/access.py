"""Who may do what on the bus: identities, their rights, and the Zenoh `access_control` rules.

Every process joins a router as an *identity* (user/password, checked by the router against
the deployment's `users.txt`); a router joins another router over mutual TLS, identified by its
certificate's common name. The router enforces, by key expression, with default *deny*:

- every authenticated identity may subscribe to `ct/**`, receive what it subscribed to, and
  declare its own liveliness token, health key and `config` queryable (`operator` also the
  take lease, `ct/{rig}/lease/*`: one take at a time per rig);
- only the identities in `PUBLISHERS` may publish a topic: the outputs each node declares in
  deploy/dataflow.yaml (only the planner publishes setpoints; only `operator` sends vehicle and
  planner commands);
- only `operator` may query a node's `config` (the safety limits).

A router-to-router link carries every identity of the far side, so a link identity is the
union of those (`LINKS`): the onboard router lets the ground router forward commands, never
setpoints.

Rights are bound to how a peer arrives: a user name counts only on a local link (plain TCP,
which deploy and every node refuse off loopback), a certificate only on a TLS link. Over TLS a
peer may do what its certificate's common name may do and nothing more, whatever user name and
password it logs in with; the two subjects never add up. The tables refer to the topic table in
`keys`, so a new topic without a publisher here fails tests/unit/test_access.py.
"""
from __future__ import annotations

from pathlib import Path

from cinetransfer.shared import dataflow, keys
from cinetransfer.shared.errors import ConfigError

OPERATOR = "operator"  # the operator's tools: `cinetransfer transfer`, command senders
OBSERVER = "observer"  # read-only tools: `monitor`, `deploy up/status` liveliness checks

def _publishers() -> dict[keys.Topic, tuple[str, ...]]:
    flow = dataflow.load()
    return {t: flow.publishers(t) for t in keys.TOPICS}


#: topic -> identities that may publish it (everybody authenticated may subscribe): exactly the
#: outputs each node declares in deploy/dataflow.yaml
PUBLISHERS: dict[keys.Topic, tuple[str, ...]] = _publishers()
#: identities that may query `ct/<rig>/<node>/config`
CONFIG_READERS: tuple[str, ...] = (OPERATOR,)

#: every node of the dataflow that joins the bus as itself (tools are OPERATOR / OBSERVER)
NODE_IDENTITIES = tuple(n.name for n in dataflow.load().nodes.values()
                        if not n.external and (n.inputs or n.outputs))
TOOL_IDENTITIES = (OPERATOR, OBSERVER)
#: router-to-router links: the link identity (certificate CN) and the identities behind it
LINKS: dict[str, tuple[str, ...]] = {
    "ground": ("source", "detector", "file_detector", "smoother", "output_detector", "camera", OPERATOR, OBSERVER),
    "onboard": ("planner", "autopilot_bridge"),
}
#: identities that get a password in users.txt / a certificate from `deploy certs`
USER_IDENTITIES = (*NODE_IDENTITIES, *TOOL_IDENTITIES, *LINKS)
CERT_IDENTITIES = (*LINKS, OPERATOR)
#: which host of a split deployment holds whose secrets (`deploy certs` writes one folder each):
#: its own identities' passwords, its router's certificate and key; the CA key stays on the ground.
#: The onboard router also holds the ground link's password: it is the one that checks it.
HOST_USERS: dict[str, tuple[str, ...]] = {
    "ground": (*dict.fromkeys([*LINKS["ground"], *TOOL_IDENTITIES, "ground"]),),
    "onboard": (*dict.fromkeys([*LINKS["onboard"], *TOOL_IDENTITIES, "onboard", "ground"]),),
}
#: (A ground tool reaches the drone through the ground router, so no operator certificate is needed there.)
HOST_CERTS: dict[str, tuple[str, ...]] = {"ground": ("ground",), "onboard": ("onboard",)}
#: the links a user name counts on (local only) and those a certificate counts on
LOCAL_PROTOCOLS = ["tcp", "unixsock-stream"]
TLS_PROTOCOLS = ["tls", "quic"]

_ALL = f"{keys.ROOT}/**"
_RECEIVE = ["put", "delete", "query"]  # egress: delivered to a subscriber / queryable
_COMMON = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "reply"]


def rights(identity: str, grants: dict[str, list[str]] | None = None) -> dict[str, list[str]]:
    """The key expressions `identity` may publish (`put`), query and self-declare on."""
    put = [f"{keys.ROOT}/*/{t.service}/{t.topic}" for t, who in PUBLISHERS.items() if identity in who]
    put += list((grants or {}).get(identity, []))
    own = [f"{keys.ROOT}/*/health/{identity}"]
    return {"put": [*put, *own],
            "query": [f"{keys.ROOT}/*/*/config"] if identity in CONFIG_READERS else [],
            "liveliness_token": [f"{keys.ROOT}/*/alive/{identity}",
                                 *([f"{keys.ROOT}/*/lease/*"] if identity == OPERATOR else [])],
            "declare_queryable": [f"{keys.ROOT}/*/{identity}/config"]}


def access_control(*, grants: dict[str, list[str]] | None = None, links: bool = True) -> dict:
    """The Zenoh `access_control` object for a router: default deny, the rights above.

    `grants` adds keys an identity may publish (e.g. a test relay); with `links`, the rules also
    admit the certificate identities (routers of LINKS, a remote operator) on TLS links, by common
    name. User-name subjects are limited to local links, so over TLS only the certificate counts.
    """
    grants = grants or {}
    users = list(dict.fromkeys([*NODE_IDENTITIES, *TOOL_IDENTITIES, *grants]))
    rules: list[dict] = [
        {"id": "common", "permission": "allow", "flows": ["ingress", "egress"], "messages": _COMMON,
         "key_exprs": [_ALL]},
        {"id": "receive", "permission": "allow", "flows": ["egress"], "messages": _RECEIVE, "key_exprs": [_ALL]},
        # tokens and queryables travel both ways between routers; anyone may *receive* them
        {"id": "declarations-out", "permission": "allow", "flows": ["egress"],
         "messages": ["liveliness_token", "declare_queryable"], "key_exprs": [_ALL]},
    ]
    subjects: list[dict] = []
    policies: list[dict] = []

    def add(subject_id: str, subject: dict, behind: list[str]) -> None:
        merged: dict[str, list[str]] = {"put": [], "query": [], "liveliness_token": [], "declare_queryable": []}
        for who in behind:
            for msg, exprs in rights(who, grants).items():
                merged[msg] += [e for e in exprs if e not in merged[msg]]
        ids = ["common", "receive", "declarations-out"]
        for msg, exprs in merged.items():
            if exprs:
                rid = f"{subject_id}:{msg}"
                rules.append({"id": rid, "permission": "allow", "flows": ["ingress"], "messages": [msg],
                              "key_exprs": exprs})
                ids.append(rid)
        subjects.append({"id": subject_id, **subject})
        policies.append({"id": f"{subject_id}-policy", "rules": ids, "subjects": [subject_id]})

    for u in users:
        add(u, {"usernames": [u], "link_protocols": LOCAL_PROTOCOLS}, [u])
    if links:
        for cn in CERT_IDENTITIES:
            subject = {"cert_common_names": [cn], "link_protocols": TLS_PROTOCOLS}
            add(f"cert-{cn}", subject, list(LINKS.get(cn, (cn,))))
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def read_password(secrets_dir: str | Path, identity: str) -> str:
    """`identity`'s password from the deployment's users.txt (ConfigError naming what is missing)."""
    path = Path(secrets_dir) / "users.txt"
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise ConfigError(f"no credentials at {path}: run 'cinetransfer deploy certs {secrets_dir}' "
                         f"(or 'deploy up', which creates them for its run folder)") from None
    for line in lines:
        user, sep, pw = line.partition(":")
        if sep and user == identity:
            return pw
    raise ConfigError(f"{path} has no password for identity {identity!r}")
