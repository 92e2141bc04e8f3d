#!/usr/bin/env bash
# Tile server throughput with wrk on loopback: random full-resolution 256x256 JPEG tiles of a
# store's mosaic (warm cache after the first seconds). Needs wrk (Debian package).
#   bench/run_serve.sh STORE [seconds]
set -euo pipefail
store=$1 seconds=${2:-10}
root=$(cd "$(dirname "$0")/.." && pwd)
port=18200
"$root/build/rolamos" serve "$store" --port $port > /tmp/rolamos-serve-bench.log 2>&1 &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
sleep 1.5
info=$(curl -s "http://127.0.0.1:$port/api/images")
zoom=$(echo "$info" | /usr/bin/python3 -c 'import json,sys; m=[i for i in json.load(sys.stdin) if i["name"]=="mosaic"][0]; print(m["xyz_max_zoom"], (m["width"]+255)//256-1, (m["height"]+255)//256-1)')
read -r z xmax ymax <<< "$zoom"
cat > /tmp/rolamos-tiles.lua <<LUA
math.randomseed(7)
request = function()
  return wrk.format("GET", "/tiles/mosaic/$z/" .. math.random(0, $xmax) .. "/" .. math.random(0, $ymax) .. ".jpg")
end
LUA
wrk -t2 -c8 -d1s -s /tmp/rolamos-tiles.lua http://127.0.0.1:$port/ > /dev/null  # warm the cache
wrk -t2 -c8 -d${seconds}s -s /tmp/rolamos-tiles.lua --latency http://127.0.0.1:$port/
grep VmHWM /proc/$server/status
