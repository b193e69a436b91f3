//! The gallery in docs/gallery still shows what this code renders: every
//! entry's small check image, rendered again, has the recorded pixels
//! (`eikon gallery --check`). When this fails, the code changed what the
//! pictures show: make them again with `cargo run --release -- gallery`.

use std::path::Path;
mod binary;

#[test]
fn gallery_matches_what_the_code_renders() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = root.join("docs/gallery/gallery.toml");
    let out = binary::eikon(&[
        "gallery",
        "--check",
        "--manifest",
        manifest.to_str().unwrap(),
    ]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    println!("{stdout}");
    assert!(out.status.success(), "{stderr}");
    // Every picture the gallery page shows is in the manifest.
    let page = std::fs::read_to_string(root.join("docs/GALLERY.md")).unwrap();
    let listed = std::fs::read_to_string(&manifest).unwrap();
    for line in page.lines().filter(|l| l.starts_with("![")) {
        // An animation (the orbit's GIF) is made by the command beside it
        // on the page, not by the manifest of stills: it must be there.
        if let Some(gif) = line
            .split("(gallery/")
            .nth(1)
            .and_then(|r| r.split_once(".gif)"))
        {
            let path = root.join("docs/gallery").join(format!("{}.gif", gif.0));
            let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(
                bytes.starts_with(b"GIF89a"),
                "{} is not a GIF",
                path.display()
            );
            continue;
        }
        let file = line
            .split("(gallery/")
            .nth(1)
            .and_then(|r| r.split(".png").next());
        let name = file.unwrap_or_else(|| panic!("unexpected picture line {line}"));
        assert!(
            listed.contains(&format!("name = \"{name}\"")),
            "docs/GALLERY.md shows {name}.png, which docs/gallery/gallery.toml does not make"
        );
        assert!(
            stdout.contains(&format!("{name}: matches")),
            "{name} was not checked"
        );
    }
}
