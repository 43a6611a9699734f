#!/usr/bin/env bash
# deploy/kubernetes/*.yaml validate against the Kubernetes API schemas and
# the prometheus-operator CRD's (kubernetes-models, pinned in
# deploy/kubernetes/validate, installed by deploy/debian/setup.sh), and
# known-bad manifests do not.
# usage: kubernetes.sh DEPLOY_KUBERNETES_DIR
set -euo pipefail
dir=$1
if [ ! -d "$dir/validate/node_modules/kubernetes-models" ]; then
  echo "FAIL: $dir/validate/node_modules is missing: run deploy/debian/setup.sh"
  exit 1
fi
node "$dir/validate/validate.mjs" "$dir"/*.yaml
node "$dir/validate/validate.mjs" --expect-invalid "$dir/validate/invalid.yaml"
echo "2 passed, 0 failed"
