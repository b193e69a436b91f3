//! WGSL shared with Rust, defined once.
//!
//! The GPU backends run the same physics as the CPU code in WGSL. What both
//! sides must agree on is written here once and generated for the other:
//!
//! * **Layouts.** Every uniform block a kernel reads is a `#[repr(C)]` Rust
//!   struct declared with [`layout!`]: named fields, no implicit padding
//!   (checked at compile time), `Pod` for upload. Its WGSL declaration is
//!   generated from the same field list ([`Layout::declaration`]), so a kernel
//!   never indexes a word array by number. `eikon_gpu::layout::check`
//!   holds every struct's WGSL member offsets (as naga lays them out) to
//!   the Rust `offset_of!`.
//! * **Constants and enums** (fates, tally slots, workgroup size, light
//!   kinds, ...) are emitted from their Rust values with [`Consts`].
//! * **Modules.** A piece of WGSL that several kernels share (the grid's
//!   cell-centre trilinear sample, the ray equation's steps, Fresnel,
//!   Henyey-Greenstein, the HistoPyramid) is a [`Module`] that lives beside
//!   the Rust it mirrors; [`compose`] puts a kernel together from its
//!   generated declarations, the modules it needs (each once, in dependency
//!   order) and its own source.
//!
//! A module may call functions it does not define, *hooks*, which every
//! kernel that includes it must provide (documented at the top of the
//! module): WGSL has no function pointers, and a hook lets the ray equation
//! read whichever index field a kernel binds.

pub use bytemuck;

/// A Rust type with a WGSL counterpart of the same size and layout.
pub trait WgslType {
    /// The WGSL type, e.g. `vec3<f32>`.
    fn wgsl() -> String;
}

macro_rules! scalar {
    ($t:ty, $w:literal) => {
        impl WgslType for $t {
            fn wgsl() -> String {
                $w.into()
            }
        }
        impl WgslType for [$t; 2] {
            fn wgsl() -> String {
                concat!("vec2<", $w, ">").into()
            }
        }
        impl WgslType for [$t; 3] {
            fn wgsl() -> String {
                concat!("vec3<", $w, ">").into()
            }
        }
        impl WgslType for [$t; 4] {
            fn wgsl() -> String {
                concat!("vec4<", $w, ">").into()
            }
        }
    };
}
scalar!(f32, "f32");
scalar!(u32, "u32");
scalar!(i32, "i32");

/// A column-major 4x4 matrix (glam's `to_cols_array_2d`).
impl WgslType for [[f32; 4]; 4] {
    fn wgsl() -> String {
        "mat4x4<f32>".into()
    }
}

/// An array of structs, `array<T, N>`.
impl<T: Layout, const N: usize> WgslType for [T; N] {
    fn wgsl() -> String {
        format!("array<{}, {N}>", T::NAME)
    }
}

/// One member of a [`Layout`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    /// Its name, the same in Rust and WGSL.
    pub name: &'static str,
    /// Its WGSL type.
    pub wgsl: String,
    /// Byte offset in the Rust struct (`offset_of!`).
    pub offset: usize,
}

/// A struct shared with WGSL (declare it with [`layout!`]).
pub trait Layout: bytemuck::Pod {
    /// The struct's name, the same in Rust and WGSL.
    const NAME: &'static str;
    /// Its members in order.
    fn members() -> Vec<Member>;
    /// Its WGSL declaration.
    fn declaration() -> String {
        let mut s = format!("struct {} {{\n", Self::NAME);
        for m in Self::members() {
            s.push_str(&format!("    {}: {},\n", m.name, m.wgsl));
        }
        s.push_str("}\n");
        s
    }
    /// Its size in bytes.
    fn size() -> usize {
        std::mem::size_of::<Self>()
    }
}

/// Declare a `#[repr(C)]` struct shared with WGSL: the Rust struct (with
/// `Clone`, `Copy`, `Debug`, `Default`, `Pod`, `Zeroable`) and its
/// [`Layout`]. Fields are `f32`, `u32`, `i32`, arrays of 2 to 4 of them
/// (WGSL vectors), `[[f32; 4]; 4]` (a column-major `mat4x4<f32>`), other
/// layouts or arrays of them. The struct may have no
/// implicit padding (a compile-time check): pad by hand with named fields,
/// so that the WGSL alignment rules (a `vec3` aligned to 16 bytes) and the
/// Rust layout agree; `eikon_gpu::layout::check` verifies that they do.
#[macro_export]
macro_rules! layout {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $( $(#[$fmeta:meta])* $fvis:vis $field:ident : $ty:ty ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default)]
        $vis struct $name {
            $( $(#[$fmeta])* $fvis $field: $ty ),*
        }
        // No implicit padding: the fields' sizes add up to the struct's.
        const _: () = assert!(
            ::core::mem::size_of::<$name>() == 0 $( + ::core::mem::size_of::<$ty>() )*,
            concat!("implicit padding in ", stringify!($name)),
        );
        // SAFETY: `repr(C)`, every field `Pod`, no padding (checked above).
        unsafe impl $crate::bytemuck::Zeroable for $name {}
        // SAFETY: as above.
        unsafe impl $crate::bytemuck::Pod for $name {}
        impl $crate::Layout for $name {
            const NAME: &'static str = stringify!($name);
            fn members() -> ::std::vec::Vec<$crate::Member> {
                ::std::vec![$( $crate::Member {
                    name: stringify!($field),
                    wgsl: <$ty as $crate::WgslType>::wgsl(),
                    offset: ::core::mem::offset_of!($name, $field),
                } ),*]
            }
        }
        impl $crate::WgslType for $name {
            fn wgsl() -> ::std::string::String {
                stringify!($name).into()
            }
        }
    };
}

/// WGSL constant declarations made from Rust values.
#[derive(Clone, Debug, Default)]
pub struct Consts(String);

impl Consts {
    /// No constants yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// `const NAME: u32 = v;`
    pub fn u32(mut self, name: &str, v: u32) -> Self {
        self.0.push_str(&format!("const {name}: u32 = {v}u;\n"));
        self
    }

    /// `const NAME: i32 = v;`
    pub fn i32(mut self, name: &str, v: i32) -> Self {
        self.0.push_str(&format!("const {name}: i32 = {v}i;\n"));
        self
    }

    /// `const NAME: f32 = v;`, written so that it reads back as the same
    /// `f32`. Panics on a non-finite value (WGSL has no literal for it).
    pub fn f32(mut self, name: &str, v: f32) -> Self {
        self.0
            .push_str(&format!("const {name}: f32 = {};\n", f32_literal(v)));
        self
    }

    /// The declarations.
    pub fn wgsl(&self) -> &str {
        &self.0
    }
}

/// A WGSL literal of `v` that parses back to the same `f32` (Rust's
/// shortest round-trip form, which always has a `.` or an exponent).
pub fn f32_literal(v: f32) -> String {
    assert!(v.is_finite(), "WGSL has no literal for {v}");
    format!("{v:?}")
}

/// A piece of WGSL shared by several kernels, beside the Rust it mirrors.
#[derive(Debug)]
pub struct Module {
    /// Its name (for the composed source's comments and de-duplication).
    pub name: &'static str,
    /// Modules it calls into.
    pub requires: &'static [&'static Module],
    /// Declarations generated from Rust (layouts, constants) that its text
    /// uses.
    pub declarations: fn() -> String,
    /// Its WGSL functions.
    pub text: &'static str,
}

/// No generated declarations.
pub fn nothing() -> String {
    String::new()
}

/// A kernel's full WGSL: `declarations` (its own generated layouts and
/// constants), then every module in `modules` with what they require, each
/// once and after what it requires, then `main`, the kernel's own source.
pub fn compose(declarations: &str, modules: &[&'static Module], main: &str) -> String {
    fn visit(m: &'static Module, seen: &mut Vec<&'static str>, out: &mut String) {
        if seen.contains(&m.name) {
            return;
        }
        seen.push(m.name);
        for r in m.requires {
            visit(r, seen, out);
        }
        out.push_str(&format!("// ---- module {} ----\n", m.name));
        out.push_str(&(m.declarations)());
        out.push_str(m.text);
        out.push('\n');
    }
    let mut out = String::from("// ---- generated from Rust ----\n");
    out.push_str(declarations);
    let mut seen = Vec::new();
    for m in modules {
        visit(m, &mut seen, &mut out);
    }
    out.push_str("// ---- kernel ----\n");
    out.push_str(main);
    out
}

fn vector_declarations() -> String {
    Consts::new()
        .f32("PI", std::f32::consts::PI)
        .wgsl()
        .to_string()
}

/// `PI` and small vector helpers every kernel uses (WGSL's builtins lack them).
pub static VECTOR: Module = Module {
    name: "vector",
    requires: &[],
    declarations: vector_declarations,
    text: include_str!("vector.wgsl"),
};

#[cfg(test)]
mod tests {
    use super::*;

    layout! {
        /// A test layout.
        struct Inner {
            a: [f32; 3],
            b: u32,
        }
    }

    layout! {
        struct Outer {
            x: f32,
            pad: [u32; 3],
            inner: [Inner; 2],
        }
    }

    #[test]
    fn layouts_declare_their_members() {
        assert_eq!(
            Inner::declaration(),
            "struct Inner {\n    a: vec3<f32>,\n    b: u32,\n}\n"
        );
        let m = Outer::members();
        assert_eq!(m[2].wgsl, "array<Inner, 2>");
        assert_eq!(m[2].offset, 16);
        assert_eq!(Outer::size(), 48);
    }

    #[test]
    fn float_literals_round_trip() {
        for v in [
            0.5f32,
            1e-9,
            0.9999,
            3.4028235e38,
            1.0,
            -2.0,
            f32::MIN_POSITIVE,
        ] {
            let s = f32_literal(v);
            assert!(s.contains('.') || s.contains('e'), "{s}");
            assert_eq!(s.parse::<f32>().unwrap(), v);
        }
        let c = Consts::new().u32("A", 3).f32("B", 0.25).i32("C", -1);
        assert_eq!(
            c.wgsl(),
            "const A: u32 = 3u;\nconst B: f32 = 0.25;\nconst C: i32 = -1i;\n"
        );
    }

    static LEAF: Module = Module {
        name: "leaf",
        requires: &[],
        declarations: nothing,
        text: "fn leaf() {}",
    };
    static MID: Module = Module {
        name: "mid",
        requires: &[&LEAF],
        declarations: nothing,
        text: "fn mid() { leaf(); }",
    };

    #[test]
    fn modules_come_once_after_what_they_require() {
        let s = compose("const K: u32 = 1u;\n", &[&MID, &LEAF], "fn main() {}");
        assert_eq!(s.matches("fn leaf()").count(), 1);
        assert!(s.find("fn leaf()").unwrap() < s.find("fn mid()").unwrap());
        assert!(s.find("const K").unwrap() < s.find("fn leaf()").unwrap());
        assert!(s.ends_with("fn main() {}"));
    }
}
