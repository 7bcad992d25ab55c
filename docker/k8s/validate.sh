#!/usr/bin/env bash
# Validates the Kubernetes manifests offline: every document against the Kubernetes API schemas
# (kubernetes-validate, strict: unknown fields are errors), and the router's HAProxy
# configuration with `haproxy -c` (Debian's haproxy; apt-get installs it when missing).
#   bash docker/k8s/validate.sh   (a few seconds; scripts/test.sh runs it)
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$PWD
source scripts/setup.sh
TOOLS=$ROOT/out/docker/tools
make_venv "$TOOLS" 11
pip_install_once "$TOOLS" "$(sha256sum docker/requirements-tools.txt | cut -d' ' -f1)" -r docker/requirements-tools.txt
KUBERNETES_VERSION=${KUBERNETES_VERSION:-1.30}
echo "== kubernetes-validate --strict -k $KUBERNETES_VERSION docker/k8s/*.yaml"
"$TOOLS/bin/kubernetes-validate" --strict -k "$KUBERNETES_VERSION" docker/k8s/*.yaml
command -v haproxy >/dev/null || [ -x /usr/sbin/haproxy ] || apt_install haproxy
config=$(mktemp)
trap 'rm -f "$config"' EXIT
"$TOOLS/bin/python" - "$config" <<'PY'
import sys
import yaml
with open("docker/k8s/router.yaml") as f:
    docs = [d for d in yaml.safe_load_all(f) if d and d.get("kind") == "ConfigMap"]
open(sys.argv[1], "w").write(docs[0]["data"]["haproxy.cfg"])
PY
echo "== haproxy -c (the router's configuration)"
"$(command -v haproxy || echo /usr/sbin/haproxy)" -c -f "$config"
echo "== manifests valid"
