# Shared by tools/run, tools/task, tools/test, ...: the repository root, the build, the
# multicast check. Also installed by the .deb, in /usr/share/stackgen/tools with the user's
# scripts (/usr/bin/stackgen-run and the like link to them): there the programs are the
# package's, nothing is built and apt brought what they need.
# shellcheck shell=bash

# (through the links: /usr/bin/stackgen-run -> /usr/share/stackgen/tools/run)
root=$(cd "$(dirname "$(readlink -f "${BASH_SOURCE[0]}")")/.." && pwd)
build="$root/build"  # (installed: absent; Python finds the package where the .deb put it)
if [ -f "$root/CMakeLists.txt" ]; then
  installed=0
  bin=${STACKGEN_BIN_DIR:-$build/bin}
else
  installed=1
  bin=${STACKGEN_BIN_DIR:-$(cd "$root/../../bin" && pwd)}
fi
export STACKGEN_BIN_DIR="$bin"

# installs what is missing (tools/install-deps, apt-get); nothing in an installed copy
install_deps() {
  [ "$installed" -eq 1 ] || "$root/tools/install-deps" "$@"
}

# configures (once) and builds the given targets (all when none) into build/, quietly: one
# line on stderr (what was built, or that nothing needed to be), the compiler's output in
# build/build.log; on a failure the end of that log and a non-zero status.
build_targets() {
  [ "$installed" -eq 0 ] || return 0
  if [ ! -f "$build/CMakeCache.txt" ]; then
    mkdir -p "$build"
    echo "stackgen: configuring build/ (first build; log: build/configure.log)" >&2
    # Ninja: an up-to-date check takes a fraction of a second, where Make's takes seconds (each
    # tools/run pays it; a folder configured before keeps its generator)
    cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      >"$build/configure.log" 2>&1 || {
      cat "$build/configure.log" >&2
      echo "stackgen: cmake configure failed (log above)" >&2
      return 1
    }
  fi
  local jobs targets=()
  jobs=$(nproc 2>/dev/null || echo 2)
  [ $# -eq 0 ] || targets=(--target "$@")
  local started=$SECONDS
  if ! cmake --build "$build" -j"$jobs" "${targets[@]}" >"$build/build.log" 2>&1; then
    tail -n 40 "$build/build.log" >&2
    echo "stackgen: the build failed (the end of build/build.log above)" >&2
    return 1
  fi
  local compiled
  compiled=$(grep -c -E '^\[ *[0-9]+(%|/[0-9]+)\] (Building|Linking)' "$build/build.log" || true)
  if [ "$compiled" -eq 0 ]; then
    echo "stackgen: build up to date" >&2
  else
    echo "stackgen: built in $((SECONDS - started)) s ($compiled steps; log: build/build.log)" >&2
  fi
}

# runs "$@" (exec) so that it gets SIGTERM when the shell that started it dies, by SIGKILL too:
# no generator or writer of a killed tools/run or tools/task lives on (setpriv, util-linux).
# Use as `die_with_parent PROGRAM ARGS... &`.
die_with_parent() {
  exec setpriv --pdeathsig TERM -- "$@"
}

# makes sure UDP multicast can leave this process: adds a loopback route when there is none and
# we are root, else says how.
ensure_multicast() {
  if ip route get 239.255.76.67 >/dev/null 2>&1; then return 0; fi
  if [ "$(id -u)" -eq 0 ] && ip route add 224.0.0.0/4 dev lo 2>/dev/null; then
    echo "stackgen: added a multicast route on lo (224.0.0.0/4)"
    return 0
  fi
  echo "stackgen: no route for multicast; run: sudo ip route add 224.0.0.0/4 dev lo" >&2
  return 1
}

# a UDP port that nothing on this host is bound to right now.
free_udp_port() {
  python3 - <<'PY' 2>/dev/null || echo $((20000 + RANDOM % 20000))
import socket
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("", 0))
print(s.getsockname()[1])
PY
}
