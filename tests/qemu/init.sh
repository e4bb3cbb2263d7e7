#!/bin/busybox sh
# /init of the test initramfs: console on virtio-console hvc0, the checks
# on the PL011 /dev/ttyAMA0, then power off. Lines the host parses:
# RESULT, TRACE, READY-FOR-SLAVE, GUEST-DONE.
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
insmod /virtio_mmio.ko
insmod /virtio_console.ko
# Wait until hvc0 can really be opened, not only until its node exists: a
# failed redirection on `exec` ends this shell, and with it init (a kernel
# panic, seen once in CI). The subshell takes the failure instead.
i=0
while ! (: </dev/hvc0) 2>/dev/null && [ $i -lt 1000 ]; do usleep 10000; i=$((i+1)); done
exec </dev/hvc0 >/dev/hvc0 2>&1
echo "GUEST-UP $(uname -r)"
/rs485_checks /dev/ttyAMA0
# Defect 5: a classic-API program that returns without a close.
/rs485_checks set 0 0 0
/classic_noclose /dev/ttyAMA0
echo "classic_noclose exit $?"
/rs485_checks expect 0 0 0 classic_exit_restores_original
# The shipped vendor-style master against a FAP slave on the host end.
/rs485_checks set 0 0 0
echo READY-FOR-SLAVE
read go
/fap_master /dev/ttyAMA0 7 3
echo "FAP-MASTER-EXIT $?"
/rs485_checks expect 0 0 0 fap_master_restores_original
echo GUEST-DONE
poweroff -f
