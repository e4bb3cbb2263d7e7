#!/bin/busybox sh
# /init of the x86 test initramfs: console on virtio-console hvc0; the
# checks on the 16550s (ttyS0 ISA, ttyS2 PCI) and the FTDI adapter
# (ttyUSB0), one port at a time; then power off. Lines the host parses:
# RESULT, TRACE, HELD, PROBE-END, DRAIN-*, READY-FOR-SLAVE, GUEST-DONE.
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
for m in virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci \
         virtio_console usb-common usbcore xhci-hcd xhci-pci usbserial ftdi_sio; do
  insmod /$m.ko || echo "insmod $m failed" >/dev/kmsg
done
i=0
while ! (: </dev/hvc0) 2>/dev/null && [ $i -lt 1000 ]; do usleep 10000; i=$((i+1)); done
exec </dev/hvc0 >/dev/hvc0 2>&1
echo "GUEST-UP $(uname -r)"
i=0
while [ ! -e /dev/ttyUSB0 ] && [ $i -lt 1000 ]; do usleep 10000; i=$((i+1)); done
C=/x86_checks
for port in ttyS0:isa ttyS2:pci ttyUSB0:ftdi; do
  dev=/dev/${port%%:*} l=${port##*:}
  echo "PORT $l $dev $(cat /sys/class/tty/${port%%:*}/type 2>/dev/null)"
  $C info $dev $l
  for d in "0 0" "3 5"; do
    set -- $d
    $C trace $dev ${l}_high_$1_$2 1 $1 $2
    $C trace $dev ${l}_low_$1_$2 0 $1 $2
  done
  $C busy $dev $l 0
  $C check $dev $l
done
$C latency /dev/ttyUSB0 ftdi
# tcdrain waits while the host side of the line is stalled
$C drain /dev/ttyS0 isa 98304
# The shipped vendor-style master against a FAP slave on the host end.
for port in ttyS0:isa ttyUSB0:ftdi; do
  echo "READY-FOR-SLAVE ${port##*:}"
  read go
  /fap_master /dev/${port%%:*} 7 3
  echo "FAP-MASTER-EXIT ${port##*:} $?"
done
echo GUEST-DONE
poweroff -f
