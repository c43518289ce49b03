//! Which physical device a [`crate::GpuContext`] runs on.

use crate::{DeviceInfo, DeviceType, GpuError};
use std::fmt;
use std::str::FromStr;

/// Environment variable that overrides [`DeviceSelection::Auto`] (and only
/// `Auto`): same syntax as [`DeviceSelection::from_str`], e.g.
/// `GUIDING_VK_DEVICE=cpu` or `GUIDING_VK_DEVICE=name:radeon`.
pub const DEVICE_ENV: &str = "GUIDING_VK_DEVICE";

/// How to choose the physical device.
///
/// Parsed from a `--device` value by [`FromStr`] (case-insensitive keywords):
///
/// | text          | selection                      |
/// |---------------|--------------------------------|
/// | `auto`        | [`DeviceSelection::Auto`]      |
/// | `gpu`         | [`DeviceSelection::Gpu`]       |
/// | `cpu`         | [`DeviceSelection::Cpu`]       |
/// | `0`, `1`, ... | [`DeviceSelection::Index`]     |
/// | `name:TEXT`   | [`DeviceSelection::Name`]      |
///
/// Anything else is an error rather than a guess, so a typo never silently
/// benchmarks the wrong device.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum DeviceSelection {
    /// The best usable device: discrete GPU, then integrated, virtual, then a
    /// CPU implementation (lavapipe); ties go to the lower index. Overridden by
    /// the environment variable [`DEVICE_ENV`] when it is set and non-empty.
    #[default]
    Auto,
    /// Like `Auto` (same order, same override) but never a CPU implementation:
    /// fails with [`GpuError::NoMatchingDevice`] on a machine that only has
    /// lavapipe, so a GPU benchmark cannot quietly measure the CPU.
    Gpu,
    /// A CPU implementation only (`VK_PHYSICAL_DEVICE_TYPE_CPU`: lavapipe /
    /// llvmpipe, SwiftShader). What tests and CI use.
    Cpu,
    /// The device at this position in `vkEnumeratePhysicalDevices` order
    /// (see [`crate::enumerate_devices`]).
    Index(usize),
    /// The best-ranked device whose name contains this text (case-insensitive).
    Name(String),
}

impl DeviceSelection {
    /// Applies the [`DEVICE_ENV`] override: `Auto` and `Gpu` are replaced by
    /// the parsed `env` value when it is non-empty; other selections are
    /// explicit and kept. An invalid `env` value is an error, not ignored.
    pub fn resolve(&self, env: Option<&str>) -> Result<DeviceSelection, GpuError> {
        match (self, env.map(str::trim)) {
            (DeviceSelection::Auto | DeviceSelection::Gpu, Some(v)) if !v.is_empty() => {
                v.parse().map_err(|e| match e {
                    GpuError::InvalidSelection { value, reason } => GpuError::InvalidSelection {
                        value: format!("{DEVICE_ENV}={value}"),
                        reason,
                    },
                    e => e,
                })
            }
            _ => Ok(self.clone()),
        }
    }

    /// Picks a device from `devices` (which must be in enumeration order).
    /// Returns its index into `devices`.
    ///
    /// `Auto`, `Gpu`, `Cpu` and `Name` only consider usable devices
    /// ([`DeviceInfo::unusable_reason`]) when one matches; an explicit `Index`
    /// (or a `Name` that only matches unusable devices) is returned anyway, so
    /// that context creation reports the precise missing feature.
    pub fn pick(&self, devices: &[DeviceInfo]) -> Result<usize, GpuError> {
        if devices.is_empty() {
            return Err(GpuError::NoDevice);
        }
        let matches = |d: &DeviceInfo| match self {
            DeviceSelection::Auto => true,
            DeviceSelection::Gpu => d.device_type != DeviceType::Cpu,
            DeviceSelection::Cpu => d.device_type == DeviceType::Cpu,
            DeviceSelection::Index(i) => d.index == *i,
            DeviceSelection::Name(n) => d.name.to_lowercase().contains(&n.to_lowercase()),
        };
        let best = |usable_only: bool| {
            devices
                .iter()
                .enumerate()
                .filter(|(_, d)| matches(d) && (!usable_only || d.unusable_reason().is_none()))
                .min_by_key(|(i, d)| (d.device_type.auto_rank(), *i))
                .map(|(i, _)| i)
        };
        let explicit = matches!(self, DeviceSelection::Index(_) | DeviceSelection::Name(_));
        best(true)
            .or_else(|| if explicit { best(false) } else { None })
            .ok_or_else(|| GpuError::NoMatchingDevice {
                selection: self.to_string(),
                found: describe(devices),
            })
    }
}

/// One device per line with the reason it cannot be used, for error messages.
pub(crate) fn describe(devices: &[DeviceInfo]) -> String {
    let mut s = String::new();
    for d in devices {
        s.push_str("\n  ");
        s.push_str(&d.to_string());
        if let Some(r) = d.unusable_reason() {
            s.push_str(" (unusable: ");
            s.push_str(r);
            s.push(')');
        }
    }
    if s.is_empty() {
        s.push_str("none");
    }
    s
}

impl FromStr for DeviceSelection {
    type Err = GpuError;

    fn from_str(s: &str) -> Result<Self, GpuError> {
        let t = s.trim();
        let bad = |reason| GpuError::InvalidSelection {
            value: s.to_string(),
            reason,
        };
        let lower = t.to_ascii_lowercase();
        match lower.as_str() {
            "auto" => return Ok(DeviceSelection::Auto),
            "gpu" => return Ok(DeviceSelection::Gpu),
            "cpu" => return Ok(DeviceSelection::Cpu),
            "" => return Err(bad("empty")),
            _ => {}
        }
        if lower.starts_with("name:") {
            let name = t["name:".len()..].trim();
            if name.is_empty() {
                return Err(bad("empty name after name:"));
            }
            return Ok(DeviceSelection::Name(name.to_string()));
        }
        if t.bytes().all(|b| b.is_ascii_digit()) {
            return t
                .parse()
                .map(DeviceSelection::Index)
                .map_err(|_| bad("index out of range"));
        }
        Err(bad("unknown keyword"))
    }
}

impl fmt::Display for DeviceSelection {
    /// The text [`FromStr`] parses back to the same selection.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DeviceSelection::Auto => f.write_str("auto"),
            DeviceSelection::Gpu => f.write_str("gpu"),
            DeviceSelection::Cpu => f.write_str("cpu"),
            DeviceSelection::Index(i) => write!(f, "{i}"),
            DeviceSelection::Name(n) => write!(f, "name:{n}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev(index: usize, name: &str, device_type: DeviceType, usable: bool) -> DeviceInfo {
        DeviceInfo {
            index,
            name: name.into(),
            device_type,
            driver_name: String::new(),
            driver_info: String::new(),
            api_version: (1, 3, 0),
            max_storage_buffer_range: 1 << 27,
            max_memory_allocation_size: 1 << 30,
            max_compute_work_group_count: [65535; 3],
            max_compute_work_group_invocations: 1024,
            max_push_constants_size: 128,
            max_storage_buffers_per_stage: 16,
            timestamp_period_ns: 1.0,
            timestamps: true,
            unified_memory: device_type == DeviceType::Cpu,
            compute_queue: true,
            vulkan_memory_model: usable,
        }
    }

    fn machine() -> Vec<DeviceInfo> {
        vec![
            dev(0, "llvmpipe (LLVM 15)", DeviceType::Cpu, true),
            dev(1, "Intel UHD 770", DeviceType::Integrated, true),
            dev(2, "Old Radeon", DeviceType::Discrete, false),
            dev(3, "NVIDIA RTX 4090", DeviceType::Discrete, true),
        ]
    }

    #[test]
    fn auto_prefers_usable_discrete_then_integrated_then_cpu() {
        let m = machine();
        assert_eq!(DeviceSelection::Auto.pick(&m).unwrap(), 3);
        assert_eq!(DeviceSelection::Auto.pick(&m[..3]).unwrap(), 1);
        assert_eq!(DeviceSelection::Auto.pick(&m[..1]).unwrap(), 0);
        assert_eq!(DeviceSelection::Gpu.pick(&m[..3]).unwrap(), 1);
        assert_eq!(DeviceSelection::Cpu.pick(&m).unwrap(), 0);
    }

    #[test]
    fn gpu_refuses_cpu_and_errors_list_devices() {
        let m = machine();
        let e = DeviceSelection::Gpu.pick(&m[..1]).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, GpuError::NoMatchingDevice { .. }), "{msg}");
        assert!(
            msg.contains("--device gpu") && msg.contains("llvmpipe"),
            "{msg}"
        );
        let e = DeviceSelection::Cpu.pick(&m[1..]).unwrap_err().to_string();
        assert!(e.contains("#2 Old Radeon [discrete GPU"), "{e}");
        assert!(e.contains("unusable: no vulkanMemoryModel"), "{e}");
        assert!(matches!(
            DeviceSelection::Auto.pick(&[]),
            Err(GpuError::NoDevice)
        ));
    }

    #[test]
    fn explicit_selection_keeps_unusable_device_for_a_precise_error() {
        let m = machine();
        assert_eq!(DeviceSelection::Index(2).pick(&m).unwrap(), 2);
        assert_eq!(DeviceSelection::Name("radeon".into()).pick(&m).unwrap(), 2);
        assert_eq!(DeviceSelection::Name("UHD".into()).pick(&m).unwrap(), 1);
        assert!(DeviceSelection::Index(4).pick(&m).is_err());
        assert!(DeviceSelection::Name("mali".into()).pick(&m).is_err());
    }

    #[test]
    fn env_override_applies_to_auto_and_gpu_only() {
        let auto = DeviceSelection::Auto;
        assert_eq!(auto.resolve(None).unwrap(), auto);
        assert_eq!(auto.resolve(Some("  ")).unwrap(), auto);
        assert_eq!(auto.resolve(Some("cpu")).unwrap(), DeviceSelection::Cpu);
        assert_eq!(
            DeviceSelection::Gpu.resolve(Some("1")).unwrap(),
            DeviceSelection::Index(1)
        );
        assert_eq!(
            DeviceSelection::Cpu.resolve(Some("gpu")).unwrap(),
            DeviceSelection::Cpu
        );
        let e = auto.resolve(Some("fastest")).unwrap_err().to_string();
        assert!(e.contains("GUIDING_VK_DEVICE=fastest"), "{e}");
    }
}
