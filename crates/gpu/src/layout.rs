//! Checks of composed WGSL without a device: that it parses and validates
//! (naga, as wgpu compiles it), and that every struct shared with Rust has
//! the members and offsets of its Rust declaration ([`eikon_shader::layout!`]).

use eikon_shader::Layout;

/// Parse and validate `source` as wgpu would; the error names the line.
pub fn validate(source: &str) -> Result<naga::Module, String> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .map_err(|e| e.emit_to_string(source))?;
    Ok(module)
}

/// The member offsets and the size, bytes, of the WGSL struct `name` in
/// `module` (for a struct the Rust side addresses by offset only).
pub fn offsets(module: &naga::Module, name: &str) -> Result<(Vec<u64>, u64), String> {
    let (members, span) = find_struct(module, name)?;
    Ok((
        members.iter().map(|m| m.offset as u64).collect(),
        span as u64,
    ))
}

/// The members and size of the WGSL struct `name`.
fn find_struct<'a>(
    module: &'a naga::Module,
    name: &str,
) -> Result<(&'a [naga::StructMember], u32), String> {
    let (_, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .ok_or_else(|| format!("no struct {name} in the shader"))?;
    let naga::TypeInner::Struct { members, span } = &ty.inner else {
        return Err(format!("{name} is not a struct"));
    };
    Ok((members, *span))
}

/// Whether `T`'s WGSL struct in `module` (as naga lays it out) has the
/// members, in order, at the byte offsets of the Rust struct, and its size.
pub fn check<T: Layout>(module: &naga::Module) -> Result<(), String> {
    let (members, span) = find_struct(module, T::NAME)?;
    let rust = T::members();
    if members.len() != rust.len() {
        return Err(format!(
            "{}: {} members in WGSL, {} in Rust",
            T::NAME,
            members.len(),
            rust.len()
        ));
    }
    for (w, r) in members.iter().zip(&rust) {
        let name = w.name.as_deref().unwrap_or("?");
        if name != r.name || w.offset as usize != r.offset {
            return Err(format!(
                "{}: WGSL member {name} at offset {}, Rust {} at {}",
                T::NAME,
                w.offset,
                r.name,
                r.offset
            ));
        }
    }
    if span as usize != T::size() {
        return Err(format!(
            "{}: {span} bytes in WGSL, {} in Rust",
            T::NAME,
            T::size()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use eikon_shader::layout;

    layout! {
        struct Good {
            a: [f32; 3],
            b: u32,
            c: [u32; 2],
            d: f32,
            e: f32,
        }
    }

    layout! {
        // A vec3 after a scalar: WGSL aligns it to 16, Rust packs it at 4.
        struct Bad {
            a: f32,
            b: [f32; 3],
        }
    }

    fn module_of(decl: &str, name: &str) -> naga::Module {
        validate(&format!(
            "{decl}\n@group(0) @binding(0) var<uniform> u: {name};\n@compute @workgroup_size(1) fn main() {{ _ = u; }}"
        ))
        .unwrap()
    }

    #[test]
    fn offsets_are_checked_against_naga() {
        check::<Good>(&module_of(&Good::declaration(), "Good")).unwrap();
        let err = check::<Bad>(&module_of(&Bad::declaration(), "Bad")).unwrap_err();
        assert!(err.contains("member b at offset 16"), "{err}");
    }

    #[test]
    fn invalid_wgsl_names_the_line() {
        let err = validate("fn f() -> u32 { return 1.5; }").unwrap_err();
        assert!(err.contains("1.5") || err.contains("return"), "{err}");
    }
}
