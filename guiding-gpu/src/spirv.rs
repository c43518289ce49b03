//! A minimal SPIR-V reader: just enough of the module's preamble to check a
//! kernel's arguments before the driver sees them (drivers may crash on a
//! missing entry point or a binding that has no descriptor).
//!
//! Reads (SPIR-V 1.6 spec, §2.3 "Physical Layout" and §3 opcodes): the header,
//! `OpCapability`, `OpEntryPoint`, `OpExecutionMode LocalSize`,
//! `OpDecorate DescriptorSet/Binding` and `OpVariable`. Everything else is skipped
//! by its word count.

use crate::GpuError;

const MAGIC: u32 = 0x0723_0203;
const OP_CAPABILITY: u32 = 17;
const OP_ENTRY_POINT: u32 = 15;
const OP_EXECUTION_MODE: u32 = 16;
const OP_DECORATE: u32 = 71;
const OP_VARIABLE: u32 = 59;
const EXECUTION_MODEL_GL_COMPUTE: u32 = 5;
const EXECUTION_MODE_LOCAL_SIZE: u32 = 17;
const DECORATION_BINDING: u32 = 33;
const DECORATION_DESCRIPTOR_SET: u32 = 34;
const STORAGE_CLASS_UNIFORM: u32 = 2;
const STORAGE_CLASS_PUSH_CONSTANT: u32 = 9;
const STORAGE_CLASS_STORAGE_BUFFER: u32 = 12;

/// A descriptor-bound variable of an entry point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Binding {
    pub set: u32,
    pub binding: u32,
    /// `StorageBuffer` (12) or `Uniform` (2).
    pub storage_class: u32,
}

/// One `GLCompute` entry point.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct EntryPoint {
    pub name: String,
    pub local_size: Option<[u32; 3]>,
    /// Descriptor bindings in the entry's interface; `None` before SPIR-V 1.4,
    /// where the interface lists only inputs and outputs.
    pub bindings: Option<Vec<Binding>>,
    /// Whether the interface has a push-constant block (`None` before SPIR-V 1.4).
    pub push_constants: Option<bool>,
}

/// What the runtime reads from a module.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct ModuleInfo {
    pub capabilities: Vec<u32>,
    pub entry_points: Vec<EntryPoint>,
}

fn bad(msg: impl Into<String>) -> GpuError {
    GpuError::InvalidSpirv(msg.into())
}

/// Decodes a nul-terminated literal string; returns it and its length in words.
fn literal_string(words: &[u32]) -> Option<(String, usize)> {
    let mut bytes = Vec::new();
    for (i, w) in words.iter().enumerate() {
        for b in w.to_le_bytes() {
            if b == 0 {
                return Some((String::from_utf8_lossy(&bytes).into_owned(), i + 1));
            }
            bytes.push(b);
        }
    }
    None
}

/// Reads the preamble of a SPIR-V module.
pub(crate) fn parse(words: &[u32]) -> Result<ModuleInfo, GpuError> {
    if words.len() < 5 {
        return Err(bad(format!(
            "{} words, shorter than the header",
            words.len()
        )));
    }
    if words[0] != MAGIC {
        return Err(bad(format!(
            "magic number {:#010x}, expected {MAGIC:#010x} (wrong endianness or not SPIR-V)",
            words[0]
        )));
    }
    let version = ((words[1] >> 16) & 0xff, (words[1] >> 8) & 0xff);
    let mut info = ModuleInfo {
        capabilities: Vec::new(),
        entry_points: Vec::new(),
    };
    // (entry id, name, interface ids), then per-id facts.
    let mut entries: Vec<(u32, String, Vec<u32>)> = Vec::new();
    let mut local_sizes: Vec<(u32, [u32; 3])> = Vec::new();
    let mut sets: Vec<(u32, u32)> = Vec::new();
    let mut bindings: Vec<(u32, u32)> = Vec::new();
    let mut variables: Vec<(u32, u32)> = Vec::new();

    let mut at = 5;
    while at < words.len() {
        let count = (words[at] >> 16) as usize;
        let opcode = words[at] & 0xffff;
        if count == 0 || at + count > words.len() {
            return Err(bad(format!("truncated instruction at word {at}")));
        }
        let ops = &words[at + 1..at + count];
        match opcode {
            OP_CAPABILITY if !ops.is_empty() => info.capabilities.push(ops[0]),
            OP_ENTRY_POINT if ops.len() >= 3 && ops[0] == EXECUTION_MODEL_GL_COMPUTE => {
                let (name, used) =
                    literal_string(&ops[2..]).ok_or_else(|| bad("unterminated entry name"))?;
                entries.push((ops[1], name, ops[2 + used..].to_vec()));
            }
            OP_EXECUTION_MODE if ops.len() >= 5 && ops[1] == EXECUTION_MODE_LOCAL_SIZE => {
                local_sizes.push((ops[0], [ops[2], ops[3], ops[4]]));
            }
            OP_DECORATE if ops.len() >= 3 && ops[1] == DECORATION_DESCRIPTOR_SET => {
                sets.push((ops[0], ops[2]));
            }
            OP_DECORATE if ops.len() >= 3 && ops[1] == DECORATION_BINDING => {
                bindings.push((ops[0], ops[2]));
            }
            OP_VARIABLE if ops.len() >= 3 => variables.push((ops[1], ops[2])),
            _ => {}
        }
        at += count;
    }

    let lookup = |table: &[(u32, u32)], id: u32| table.iter().find(|e| e.0 == id).map(|e| e.1);
    let full_interface = version >= (1, 4);
    for (id, name, interface) in entries {
        let storage = |v: &u32| lookup(&variables, *v);
        let ep_bindings = interface
            .iter()
            .filter(|v| {
                matches!(
                    storage(v),
                    Some(STORAGE_CLASS_STORAGE_BUFFER | STORAGE_CLASS_UNIFORM)
                )
            })
            .map(|v| Binding {
                set: lookup(&sets, *v).unwrap_or(0),
                binding: lookup(&bindings, *v).unwrap_or(0),
                storage_class: storage(v).unwrap_or(0),
            })
            .collect();
        let push = interface
            .iter()
            .any(|v| storage(v) == Some(STORAGE_CLASS_PUSH_CONSTANT));
        info.entry_points.push(EntryPoint {
            local_size: local_sizes.iter().find(|e| e.0 == id).map(|e| e.1),
            name,
            bindings: full_interface.then_some(ep_bindings),
            push_constants: full_interface.then_some(push),
        });
    }
    Ok(info)
}

/// Copies a SPIR-V byte blob into aligned words (SPIR-V is a stream of
/// little-endian `u32`s; `include_bytes!` only guarantees byte alignment).
pub fn words_from_bytes(bytes: &[u8]) -> Result<Vec<u32>, GpuError> {
    if bytes.len() % 4 != 0 {
        return Err(bad(format!("{} bytes, not a multiple of 4", bytes.len())));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

/// Capabilities that need a device feature, with that feature's Vulkan name.
/// Capabilities not listed here are core in Vulkan 1.2 compute (`Shader`, ...)
/// or are left to the driver / validation layer to reject.
pub(crate) const CAPABILITY_FEATURES: &[(u32, &str)] = &[
    (9, "shaderFloat16"),
    (10, "shaderFloat64"),
    (11, "shaderInt64"),
    (12, "shaderBufferInt64Atomics"),
    (22, "shaderInt16"),
    (39, "shaderInt8"),
    (4433, "storageBuffer16BitAccess"),
    (4441, "variablePointersStorageBuffer"),
    (4442, "variablePointers"),
    (4448, "storageBuffer8BitAccess"),
    (5345, "vulkanMemoryModel"),
    (5346, "vulkanMemoryModelDeviceScope"),
    (5347, "bufferDeviceAddress"),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn instr(opcode: u32, ops: &[u32]) -> Vec<u32> {
        let mut v = vec![((ops.len() as u32 + 1) << 16) | opcode];
        v.extend_from_slice(ops);
        v
    }

    /// A hand-assembled preamble: SPIR-V 1.5, Shader + Int64, Vulkan memory
    /// model, entry "main" (id 1) with interface {2 (StorageBuffer, set 0
    /// binding 1), 3 (PushConstant)}, LocalSize 64 1 1.
    fn module() -> Vec<u32> {
        let mut m = vec![MAGIC, 0x0001_0500, 0, 10, 0];
        m.extend(instr(OP_CAPABILITY, &[1]));
        m.extend(instr(OP_CAPABILITY, &[11]));
        m.extend(instr(14, &[0, 3])); // OpMemoryModel Logical Vulkan
        let name = u32::from_le_bytes(*b"main");
        m.extend(instr(OP_ENTRY_POINT, &[5, 1, name, 0, 2, 3]));
        m.extend(instr(
            OP_EXECUTION_MODE,
            &[1, EXECUTION_MODE_LOCAL_SIZE, 64, 1, 1],
        ));
        m.extend(instr(OP_DECORATE, &[2, DECORATION_DESCRIPTOR_SET, 0]));
        m.extend(instr(OP_DECORATE, &[2, DECORATION_BINDING, 1]));
        m.extend(instr(OP_VARIABLE, &[7, 2, STORAGE_CLASS_STORAGE_BUFFER]));
        m.extend(instr(OP_VARIABLE, &[8, 3, STORAGE_CLASS_PUSH_CONSTANT]));
        m
    }

    #[test]
    fn reads_the_preamble() {
        let info = parse(&module()).unwrap();
        assert_eq!(info.capabilities, vec![1, 11]);
        assert_eq!(info.entry_points.len(), 1);
        let ep = &info.entry_points[0];
        assert_eq!(ep.name, "main");
        assert_eq!(ep.local_size, Some([64, 1, 1]));
        assert_eq!(ep.push_constants, Some(true));
        let b = ep.bindings.as_ref().unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!((b[0].set, b[0].binding), (0, 1));
    }

    #[test]
    fn rejects_garbage() {
        assert!(parse(&[1, 2, 3]).is_err());
        assert!(parse(&[0x0302_2307, 0, 0, 0, 0]).is_err());
        let mut m = module();
        m.push(5 << 16 | 1); // claims 5 words, 1 present
        assert!(parse(&m).is_err());
        assert!(words_from_bytes(&[1, 2, 3]).is_err());
        assert_eq!(words_from_bytes(&[3, 2, 35, 7]).unwrap(), vec![MAGIC]);
    }
}
