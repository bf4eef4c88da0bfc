//! The catalogue of real scenes (`experiments/scenes.toml`, compiled in so it works from any
//! working directory): name, stored file, size, BLAKE3, triangles, source and licence of every
//! scene file the shipped experiments name. `bvhlab scenes fetch` verifies against it, and a missing
//! scene file that is catalogued gets the fetch command in its error message.
use crate::Error;
use serde::Deserialize;
use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;

/// The catalogue as shipped.
pub const CATALOGUE_TOML: &str = include_str!("../../../experiments/scenes.toml");

/// Where `--from` comes from when the command line gives none (a mirror of the stored files).
pub const FROM_ENV: &str = "BVHLAB_SCENES_FROM";

/// One stored file: name in the scene directory, size and BLAKE3 of its bytes.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoredFile {
    pub file: String,
    pub bytes: u64,
    pub blake3: String,
}

/// One catalogued scene.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneEntry {
    pub name: String,
    pub file: String,
    pub bytes: u64,
    pub blake3: String,
    pub triangles: u64,
    pub title: String,
    pub source: String,
    pub origin: String,
    pub licence: String,
    #[serde(default)]
    pub notes: Vec<StoredFile>,
}

impl SceneEntry {
    /// The scene file and then its notes, each as a file to fetch and verify.
    pub fn files(&self) -> Vec<StoredFile> {
        let mut v = vec![StoredFile {
            file: self.file.clone(),
            bytes: self.bytes,
            blake3: self.blake3.clone(),
        }];
        v.extend(self.notes.iter().cloned());
        v
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CatalogueToml {
    scene: Vec<SceneEntry>,
}

/// Parses a catalogue (names and files unique, checksums 64 hex digits).
pub fn parse(src: &str) -> Result<Vec<SceneEntry>, String> {
    let c: CatalogueToml = toml::from_str(src).map_err(|e| e.to_string())?;
    let mut seen = std::collections::BTreeSet::new();
    for s in &c.scene {
        if !seen.insert(s.name.clone()) {
            return Err(format!("scene `{}` listed twice", s.name));
        }
        for f in s.files() {
            let plain =
                !f.file.is_empty() && !f.file.contains(['/', '\\']) && !f.file.starts_with('.');
            if !plain {
                return Err(format!("{}: `{}` is not a plain file name", s.name, f.file));
            }
            if !seen.insert(format!("file:{}", f.file)) {
                return Err(format!("file `{}` listed twice", f.file));
            }
            if f.blake3.len() != 64
                || !f
                    .blake3
                    .bytes()
                    .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
            {
                return Err(format!(
                    "{}: blake3 of `{}` is not 64 lower-case hex digits",
                    s.name, f.file
                ));
            }
        }
    }
    Ok(c.scene)
}

/// The shipped catalogue (parsed once; a unit test keeps it parseable).
pub fn catalogue() -> &'static [SceneEntry] {
    static C: OnceLock<Vec<SceneEntry>> = OnceLock::new();
    C.get_or_init(|| {
        parse(CATALOGUE_TOML).unwrap_or_else(|e| panic!("experiments/scenes.toml: {e}"))
    })
}

pub fn by_name(name: &str) -> Option<&'static SceneEntry> {
    catalogue().iter().find(|s| s.name == name)
}

/// The catalogued scene whose stored file has this path's file name.
pub fn by_file(path: &Path) -> Option<&'static SceneEntry> {
    let name = path.file_name()?.to_str()?;
    catalogue().iter().find(|s| s.file == name)
}

/// Removes `.` and `a/..` pairs without touching the filesystem (a path shown to the user).
fn tidy(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir
                if matches!(out.components().next_back(), Some(Component::Normal(_))) =>
            {
                out.pop();
            }
            c => out.push(c),
        }
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// `bvhlab scenes fetch NAME --from ... --dir DIR` for a missing scene file at `path` (as the
/// user should have it: relative paths against the working directory), or None if the file name
/// is not catalogued. `--from` is `$BVHLAB_SCENES_FROM` when set, else a placeholder to fill in.
pub fn fetch_command(path: &Path) -> Option<String> {
    let entry = by_file(path)?;
    let dir = tidy(path.parent().unwrap_or(Path::new(".")));
    let from = match std::env::var(FROM_ENV) {
        Ok(v) if !v.is_empty() => v,
        _ => "URL|DIR".to_string(),
    };
    Some(format!(
        "bvhlab scenes fetch {} --from {from} --dir {}",
        entry.name,
        dir.display()
    ))
}

/// ` (catalogued scene NAME: ...)` to append to a missing-file message, or "".
pub fn missing_hint(path: &Path) -> String {
    match fetch_command(path) {
        Some(cmd) => {
            let from = if std::env::var(FROM_ENV).is_ok_and(|v| !v.is_empty()) {
                format!(" (--from is ${FROM_ENV})")
            } else {
                " (--from: a web address or directory holding the stored files, e.g. another machine's \
                 ../shared/scenes; the upstream sites serve other formats, see experiments/scenes.toml)"
                    .to_string()
            };
            format!("; it is a catalogued real scene, fetch and verify it with `{cmd}`{from}")
        }
        None => String::new(),
    }
}

/// The error for a scene file that cannot be read: `PATH: cannot read scene: REASON`, plus the
/// fetch command when the file is missing and catalogued.
pub fn read_error(path: &Path, e: &std::io::Error) -> Error {
    let hint = if e.kind() == std::io::ErrorKind::NotFound {
        missing_hint(path)
    } else {
        String::new()
    };
    Error::input(format!("{}: cannot read scene: {e}{hint}", path.display()))
}

/// Where an experiment's relative scene path should be fetched to so that the experiment finds it:
/// against the working directory when the experiment file sits in `<cwd>/experiments/` (the
/// repository root as working directory), else against the experiment file's parent directory
/// (the third place the experiment loader looks).
pub fn experiment_scene_path(spec: &str, exp_path: &Path) -> PathBuf {
    let p = PathBuf::from(spec);
    if p.is_absolute() {
        return p;
    }
    let root = exp_path.parent().unwrap_or(Path::new(".")).join("..");
    let same = match (root.canonicalize(), std::env::current_dir()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same {
        p
    } else {
        tidy(&root.join(p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_catalogue_parses() {
        let c = catalogue();
        assert_eq!(c.len(), 9);
        assert!(c
            .iter()
            .all(|s| s.triangles > 0 && s.bytes > 0 && !s.licence.is_empty()));
    }

    /// Every real scene path in experiments/*.toml is catalogued (by file name).
    #[test]
    fn every_experiment_scene_is_catalogued() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments");
        let mut checked = 0;
        for f in std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.path()) {
            if f.extension().is_none_or(|x| x != "toml") || f.ends_with("scenes.toml") {
                continue;
            }
            let text = std::fs::read_to_string(&f).unwrap();
            for piece in text
                .split('"')
                .filter(|s| s.ends_with(".obj") || s.ends_with(".obj.gz"))
            {
                assert!(
                    by_file(Path::new(piece)).is_some(),
                    "{}: {piece} is not in experiments/scenes.toml",
                    f.display()
                );
                checked += 1;
            }
        }
        assert!(checked > 0);
    }

    #[test]
    fn duplicates_and_bad_checksums_are_refused() {
        let one = "[[scene]]\nname = \"a\"\nfile = \"a.obj.gz\"\nbytes = 1\nblake3 = \"%H\"\ntriangles = 1\n\
                   title = \"t\"\nsource = \"s\"\norigin = \"o\"\nlicence = \"l\"\n";
        let good = one.replace("%H", &"ab".repeat(32));
        assert!(parse(&good).is_ok());
        assert!(parse(&format!("{good}{good}"))
            .unwrap_err()
            .contains("twice"));
        assert!(parse(&one.replace("%H", "abc"))
            .unwrap_err()
            .contains("hex"));
        assert!(parse(&good.replace("a.obj.gz", "../a.obj.gz"))
            .unwrap_err()
            .contains("plain"));
    }

    #[test]
    fn hint_names_the_fetch_command() {
        let p = Path::new("../shared/scenes/./stanford_dragon.obj.gz");
        let cmd = fetch_command(p).unwrap();
        assert!(
            cmd.starts_with("bvhlab scenes fetch stanford_dragon --from "),
            "{cmd}"
        );
        assert!(cmd.ends_with(" --dir ../shared/scenes"), "{cmd}");
        assert!(fetch_command(Path::new("mine.obj")).is_none());
        assert_eq!(tidy(Path::new("a/b/../../c/./d")), PathBuf::from("c/d"));
        assert_eq!(tidy(Path::new("../../x")), PathBuf::from("../../x"));
    }
}
