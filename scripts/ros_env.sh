# Source me (bash): ROS 2 Jazzy (from /opt/ros/jazzy or the project's venv) and this workspace.
# BEAMS_INSTALL_BASE selects the colcon install tree (default: install/ at the project root).
_beams_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ -f /opt/ros/jazzy/setup.bash ] && [ -z "${BEAMS_USE_WHEELS:-}" ]; then
    # shellcheck disable=SC1091
    source /opt/ros/jazzy/setup.bash
    source "$_beams_root/.venv/bin/activate"
else
    source "$_beams_root/.venv/bin/activate"
    # The ament index and CMake do not know the venv by themselves (ROS2_FROM_PYPI.md, pitfall 1).
    export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
    export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
fi
_beams_install="${BEAMS_INSTALL_BASE:-$_beams_root/install}"
if [ -f "$_beams_install/setup.bash" ]; then
    # shellcheck disable=SC1091
    source "$_beams_install/setup.bash"
fi
# A restarted node finds the others within about 0.2 s (announcements every 0.1 s, not 3 s).
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_beams_root/src/beams_bringup/config/fastdds_fast_discovery.xml}"
# Keep DDS discovery on this machine unless the user chose otherwise (a robot sets SUBNET).
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
unset _beams_root _beams_install
