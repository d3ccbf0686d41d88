#!/usr/bin/env bash
# Three "hosts" on one Linux machine, to try a multi-host run and its faults before
# spreading it over real machines (docs/architecture.md, "Runs across hosts"). Needs root,
# iproute2 and nftables. Each host is a network namespace: head at 10.77.0.1 (it holds a
# bridge), w1 at 10.77.0.2 and w2 at 10.77.0.3, each joined to the bridge by a veth pair.
#   netns.sh up                       create the three hosts
#   netns.sh run HOST CMD...          run CMD on HOST, with a /dev/shm of its own
#   netns.sh loss HOST PCT            drop PCT% of HOST's TCP packets, both ways (nftables)
#   netns.sh partition HOST SECONDS   drop all of HOST's traffic for SECONDS (silently)
#   netns.sh clear HOST               remove HOST's fault rules
#   netns.sh down                     remove the hosts
# HOST is head, w1 or w2; FFNS=name names the namespaces name-head, … (default ff), so
# that several such sets can live side by side. The kernel here has no netem qdisc, so
# there is no added latency.
set -euo pipefail
p=${FFNS:-ff}
hosts=("$p-head" "$p-w1" "$p-w2")
ns() { echo "$p-$1"; }
rules() { # HOST: the fault table of HOST, created if missing
  ip netns exec "$1" nft list table inet fffault >/dev/null 2>&1 || {
    ip netns exec "$1" nft add table inet fffault
    ip netns exec "$1" nft add chain inet fffault in '{ type filter hook input priority 0; }'
    ip netns exec "$1" nft add chain inet fffault out '{ type filter hook output priority 0; }'
  }
}
case ${1:-} in
  up)
    for h in "${hosts[@]}"; do ip netns add "$h"; ip -n "$h" link set lo up; done
    ip -n "$p-head" link add ffbr type bridge
    ip -n "$p-head" addr add 10.77.0.1/24 dev ffbr
    ip -n "$p-head" link set ffbr up
    for w in 1 2; do
      ip link add "$p-w$w-br" netns "$p-head" type veth peer name eth0 netns "$p-w$w"
      ip -n "$p-head" link set "$p-w$w-br" master ffbr up
      ip -n "$p-w$w" addr add "10.77.0.$((w + 1))/24" dev eth0
      ip -n "$p-w$w" link set eth0 up
    done
    ;;
  run)
    h=$(ns "${2:?host}"); shift 2
    # a mount namespace with its own /dev/shm: no shared memory between "hosts"
    exec ip netns exec "$h" unshare --mount --propagation private \
      sh -c 'mount -t tmpfs -o size=8g tmpfs /dev/shm && exec "$@"' sh "$@"
    ;;
  loss)
    h=$(ns "${2:?host}"); pct=${3:?percent}; rules "$h"
    for c in in out; do
      ip netns exec "$h" nft add rule inet fffault "$c" meta l4proto tcp numgen random mod 100 "<" "$pct" drop
    done
    ;;
  partition)
    h=$(ns "${2:?host}"); s=${3:?seconds}; rules "$h"
    ip netns exec "$h" nft add chain inet fffault cut '{ type filter hook output priority -1; }'
    ip netns exec "$h" nft add chain inet fffault cutin '{ type filter hook input priority -1; }'
    ip netns exec "$h" nft add rule inet fffault cut oifname != lo drop
    ip netns exec "$h" nft add rule inet fffault cutin iifname != lo drop
    sleep "$s"
    ip netns exec "$h" nft delete chain inet fffault cut
    ip netns exec "$h" nft delete chain inet fffault cutin
    ;;
  clear)
    ip netns exec "$(ns "${2:?host}")" nft delete table inet fffault 2>/dev/null || true
    ;;
  down)
    for h in "${hosts[@]}"; do ip netns del "$h" 2>/dev/null || true; done
    ;;
  *)
    sed -n '2,16p' "$0"; exit 2
    ;;
esac
