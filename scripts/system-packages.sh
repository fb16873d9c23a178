#!/bin/sh
# The system packages some tests need, installed when this machine allows it; otherwise one plain line says what
# is missing and which tests will skip for it. Called by the README's test command (and so by .ci/run).
#
#   gcc-avr avr-libc simavr libsimavr-dev libsimavrparts1   the detector board's firmware, built and run on an
#                                                           emulated ATmega328P (tests/test_firmware*.py)
#   chromium                                                the live view, checked in a headless browser
#   ngspice                                                 the detector's amplifier (hardware/frontend/frontend.cir)
#                                                           simulated: DC, phase margin, settling, noise
#                                                           (tests/test_frontend_spice.py)
#   make                                                    builds the firmware and GRBL's host simulator
#                                                           (tests/test_grbl_conformance.py; gcc is on a Python
#                                                           machine already)
#   libgl1 libx11-6                                         loaded by build123d's OpenCascade kernel (the wheel
#                                                           cadquery-ocp-novtk links libGL and libX11): the printed
#                                                           parts built and checked (tests/test_hardware_cad.py)
# Set GONIO_NO_SYSTEM_PACKAGES=1 to install nothing (those tests then skip and say why).
PKGS="make gcc-avr avr-libc simavr libsimavr-dev libsimavrparts1 chromium ngspice libgl1 libx11-6"

missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -z "$missing" ]; then
    echo "system packages: all present ($PKGS)"
    exit 0
fi
why=""
if [ -n "$GONIO_NO_SYSTEM_PACKAGES" ]; then
    why="GONIO_NO_SYSTEM_PACKAGES is set"
elif ! command -v apt-get >/dev/null 2>&1; then
    why="this machine has no apt-get"
elif [ "$(id -u)" != "0" ] && ! sudo -n true 2>/dev/null; then
    why="installing needs root (run: sudo apt-get install$missing)"
fi
if [ -z "$why" ]; then
    SUDO=""
    [ "$(id -u)" != "0" ] && SUDO="sudo -n"
    echo "system packages: installing$missing (about a minute) ..."
    if $SUDO apt-get update -qq >/dev/null 2>&1 && \
       DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null 2>&1; then
        echo "system packages: installed$missing"
        exit 0
    fi
    why="apt-get install failed (no network to Debian's mirrors?)"
fi
echo "system packages: NOT installed:$missing ($why); the firmware tests (gcc-avr, simavr), the live view's" \
     "browser test (chromium), the amplifier's circuit tests (ngspice) and the CAD tests (libgl1, libx11-6) will be skipped and say so"
exit 0
