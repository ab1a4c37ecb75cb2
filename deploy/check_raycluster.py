"""Check RayCluster manifests against KubeRay's CRD schema, offline.

Usage: ``python deploy/check_raycluster.py ray.io_rayclusters.yaml deploy/k8s/raycluster.yaml``
(the CRD file is KubeRay's ``ray-operator/config/crd/bases/ray.io_rayclusters.yaml``).

The CRD's ``openAPIV3Schema`` becomes a JSON schema: objects with declared properties reject
unknown fields (as the API server's strict field validation does) unless the schema preserves
them, ``nullable`` allows null and ``x-kubernetes-int-or-string`` allows both.
"""

from __future__ import annotations

import sys
from typing import Any

import jsonschema
import yaml


def _strict(node: Any) -> None:
    if isinstance(node, dict):
        if node.get("x-kubernetes-int-or-string"):
            node.pop("type", None)
            node["anyOf"] = [{"type": "integer"}, {"type": "string"}]
        if node.get("nullable") and isinstance(node.get("type"), str):
            node["type"] = [node["type"], "null"]
        preserves = node.get("x-kubernetes-preserve-unknown-fields")
        if node.get("type") == "object" and "properties" in node and not preserves:
            node.setdefault("additionalProperties", False)
        for value in node.values():
            _strict(value)
    elif isinstance(node, list):
        for value in node:
            _strict(value)


def main(crd_path: str, manifests: list[str]) -> int:
    """Validate every RayCluster in ``manifests``; return the number of errors."""
    with open(crd_path) as f:
        crd = yaml.safe_load(f)
    version = next(v for v in crd["spec"]["versions"] if v["name"] == "v1")
    schema = version["schema"]["openAPIV3Schema"]
    _strict(schema)
    validator = jsonschema.Draft7Validator(schema)
    failed = 0
    for path in manifests:
        with open(path) as f:
            docs = [d for d in yaml.safe_load_all(f) if d and d.get("kind") == "RayCluster"]
        for doc in docs:
            errors = [] if doc.get("apiVersion") == "ray.io/v1" else ["apiVersion is not ray.io/v1"]
            errors += [
                f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
                for e in validator.iter_errors(doc)
            ]
            for e in errors:
                print(f"{path}: {e}")
            print(f"{path}: RayCluster {doc['metadata']['name']}: {len(errors)} schema errors")
            failed += len(errors)
    return failed


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    sys.exit(1 if main(sys.argv[1], sys.argv[2:]) else 0)
