#!/bin/sh
# Runs "$@" with discovery kept on this machine: call it as `unshare -n tests/ros2/netns.sh CMD`
# (a private network namespace, root needed), where the loopback interface is brought up with
# multicast (DDS discovery is multicast) and nothing can leave the namespace. Cyclone DDS is
# told to use the loopback interface for multicast, which it does not by default.
set -e
ip link set lo up
ip link set lo multicast on
ip route add 224.0.0.0/4 dev lo 2>/dev/null || true
export CYCLONEDDS_URI='<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo" multicast="true"/></Interfaces><AllowMulticast>true</AllowMulticast></General></Domain></CycloneDDS>'
exec "$@"
