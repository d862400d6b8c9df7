# Shared by tools/run and tools/test: the repository root, the build, the multicast check.
# shellcheck shell=bash

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build="$root/build"

# configures (once) and builds the given targets (all when none) into build/.
build_targets() {
  if [ ! -f "$build/CMakeCache.txt" ]; then
    cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release >"$build.configure.log" 2>&1 || {
      cat "$build.configure.log" >&2
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

# the bus key every process of a run signs its messages with (design.md, "Trust"):
# $STACKGEN_BUS_KEY_FILE when set, else this user's key, made once (32 random bytes, base64,
# mode 600) at ${XDG_CONFIG_HOME:-~/.config}/stackgen/bus.key. Exports STACKGEN_BUS_KEY_FILE.
ensure_bus_key() {
  if [ -n "${STACKGEN_BUS_KEY_FILE:-}" ]; then export STACKGEN_BUS_KEY_FILE; return 0; fi
  local dir="${XDG_CONFIG_HOME:-$HOME/.config}/stackgen"
  STACKGEN_BUS_KEY_FILE="$dir/bus.key"
  export STACKGEN_BUS_KEY_FILE
  [ -f "$STACKGEN_BUS_KEY_FILE" ] && return 0
  mkdir -p "$dir"
  (umask 077 && head -c 32 /dev/urandom | base64 >"$STACKGEN_BUS_KEY_FILE.tmp" &&
    mv "$STACKGEN_BUS_KEY_FILE.tmp" "$STACKGEN_BUS_KEY_FILE")
  echo "stackgen: made a bus key at $STACKGEN_BUS_KEY_FILE; other processes of this bus need it" \
    "(--bus-key-file or STACKGEN_BUS_KEY_FILE)" >&2
}
