#!/usr/bin/env bash
# Print the compat/ packages (see compat/README.md) that the ROS environment lacks, for colcon's
# --base-paths: a package counts as present when a prefix other than this workspace's install tree
# (BEAMS_INSTALL_BASE) registers it in the ament index. Run with the ROS environment sourced.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
install_base="$(realpath -m "${BEAMS_INSTALL_BASE:-$root/install}")"
for package_dir in "$root"/compat/*/; do
    package="$(basename "$package_dir")"
    found=""
    IFS=: read -r -a prefixes <<< "${AMENT_PREFIX_PATH:-}"
    for prefix in "${prefixes[@]}"; do
        [ -n "$prefix" ] || continue
        case "$(realpath -m "$prefix")" in "$install_base"|"$install_base"/*) continue ;; esac
        if [ -e "$prefix/share/ament_index/resource_index/packages/$package" ]; then
            found=yes
            break
        fi
    done
    [ -n "$found" ] || echo "compat/$package"
done
