# Shared by tools/run and tools/test: the repository root, the build, the multicast check.
# shellcheck shell=bash

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build="$root/build"

# configures (once) and builds the given targets (all when none) into build/.
build_targets() {
  if [ ! -f "$build/CMakeCache.txt" ]; then
    mkdir -p "$build"
    cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release >"$build/configure.log" 2>&1 || {
      cat "$build/configure.log" >&2
      echo "stackgen: cmake configure failed (log above)" >&2
      return 1
    }
  fi
  local jobs
  jobs=$(nproc 2>/dev/null || echo 2)
  if [ $# -eq 0 ]; then
    cmake --build "$build" -j"$jobs"
  else
    cmake --build "$build" -j"$jobs" --target "$@"
  fi
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
