#!/usr/bin/env bash
# One entry point for a fresh Debian/Ubuntu machine. Idempotent.
#   bash scripts/bootstrap.sh sim [sage sim options]   set up, then start the simulated robot
#   bash scripts/bootstrap.sh test [pytest options]    set up, then run the whole test suite
#   bash scripts/bootstrap.sh lint                     set up, then ruff + mypy
#   bash scripts/bootstrap.sh setup                    set up only
# System packages come from scripts/apt-packages.txt: installed when run as root,
# otherwise the exact apt-get command is printed. Python packages go into .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
VENV="$ROOT/.venv"
STAMP="$VENV/.sage-installed"

say() { printf '\033[1m[sage setup]\033[0m %s\n' "$*" >&2; }

system_packages() {
  local wanted=() missing=()
  mapfile -t wanted < <(grep -v '^\s*#' scripts/apt-packages.txt | awk 'NF {print $1}')
  for pkg in "${wanted[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  if [ "$(id -u)" -eq 0 ]; then
    say "installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    say "missing system packages; run this once, then again this script:"
    echo "  sudo apt-get update && sudo apt-get install -y ${missing[*]}"
    exit 1
  fi
}

pick_python() {
  for py in python3.12 python3.11 python3.10 python3; do
    if command -v "$py" >/dev/null && "$py" -c 'import sys, venv; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
      echo "$py"; return 0
    fi
  done
  say "Python >= 3.10 with venv is needed: apt-get install python3 python3-venv"
  exit 1
}

python_packages() {
  if [ ! -x "$VENV/bin/python" ]; then
    local py; py=$(pick_python)
    say "creating $VENV with $py"
    "$py" -m venv "$VENV"
  fi
  local want; want=$(cat pyproject.toml scripts/bootstrap.sh scripts/pip-no-deps.txt | sha256sum | cut -c1-16)
  if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$want" ]; then return 0; fi
  say "installing Python packages into .venv (first run takes a few minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[all,dev]"
  # Packages whose declared dependencies we do not use (see the file's comments).
  local nodeps=(); mapfile -t nodeps < <(grep -v '^\s*#' scripts/pip-no-deps.txt | awk 'NF {print $1}')
  [ ${#nodeps[@]} -eq 0 ] || "$VENV/bin/python" -m pip install -q --no-deps "${nodeps[@]}"
  echo "$want" > "$STAMP"
}

# The browser tests' accessibility checker (axe-core, injected into Chromium by Playwright),
# pinned, from the npm registry into an ignored folder next to the tests.
AXE_VERSION=4.10.3
AXE_DIR="$ROOT/tests/web/.axe"
node_packages() {
  local have="$AXE_DIR/node_modules/axe-core/package.json"
  if [ -f "$have" ] && grep -q "\"version\": \"$AXE_VERSION\"" "$have"; then return 0; fi
  if ! command -v npm >/dev/null; then  # npm often comes with Node.js itself, not the apt package
    if [ "$(id -u)" -eq 0 ]; then
      say "installing npm (for the web pages' accessibility checker)"
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends npm >/dev/null
    else
      say "npm is missing (the tests' accessibility checker comes from the npm registry); run once:"
      echo "  sudo apt-get update && sudo apt-get install -y npm"
      exit 1
    fi
  fi
  say "installing axe-core $AXE_VERSION (accessibility checks of the web pages) into $AXE_DIR"
  mkdir -p "$AXE_DIR"
  npm install --silent --no-save --no-package-lock --no-audit --no-fund --prefix "$AXE_DIR" "axe-core@$AXE_VERSION"
}

setup() { system_packages; python_packages; }

cmd=${1:-sim}; shift || true
case "$cmd" in
  setup) setup ;;
  sim) setup; exec "$VENV/bin/sage" sim "$@" ;;
  test)
    setup
    node_packages  # only the tests need it
    set +e
    "$VENV/bin/python" -m pytest "$@"
    rc=$?
    set -e
    if [ "$rc" -eq 5 ]; then say "pytest collected no tests"; exit 1; fi
    exit "$rc" ;;
  lint) setup; "$VENV/bin/ruff" check src tests && "$VENV/bin/mypy" ;;
  *) echo "usage: bash scripts/bootstrap.sh sim|test|lint|setup [args]" >&2; exit 2 ;;
esac
