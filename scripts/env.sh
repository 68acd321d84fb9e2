# Sourced by the scripts: ROS from Debian under /usr, /usr/bin/python3 first (pyenv's python3 lacks
# the ROS modules), and the catkin workspace WS (default: ./.ws, git-ignored).
# Workspace layout (scripts/build.sh): WS/src/endo_stereo -> WS/endo_stereo, a folder of links to
# the repository's top-level entries (never to WS itself), so that `rosrun`, `roslaunch` and
# `rospack`, which follow links when they search a package, never loop back into the workspace.
# ES_ROOT is the repository (links resolved), also when a script is reached through WS.
ES_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)"
ES_ROOT="$(dirname "$ES_ROOT")"
export WS="${WS:-$ES_ROOT/.ws}"
export PATH="/usr/bin:/usr/lib/nodelet:$PATH"
export ROS_PYTHON_VERSION=3
export PYTHONNOUSERSITE=1
export ROS_LOG_DIR="${ROS_LOG_DIR:-$WS/log}"
es_source_ws() {
  if [ -f "$WS/devel/setup.bash" ]; then
    # shellcheck disable=SC1091
    set +u; source "$WS/devel/setup.bash"; set -u 2>/dev/null || true
  fi
}
