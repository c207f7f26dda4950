//! Opening a pair on a loading thread: a session, two volumes with their landmarks, or the demo pair, each volume
//! prepared for the window's device where it is known, so that the UI thread only uploads.

use std::sync::Arc;

use anyhow::anyhow;
use warpbench_io::{Part, Volume};

use super::viewer::{DeviceFacts, LayerData};
use super::{GuiOptions, open};
use crate::project::demo;
use crate::project::document::Document;
use crate::project::session;

/// The two volumes read, and the window's title for them.
#[derive(Debug)]
pub struct Loaded {
    pub fixed: Arc<Volume>,
    pub moving: Arc<Volume>,
    /// e.g. "cranium_ct.nii.gz -> ch2.nii.gz (demo)".
    pub title: String,
}

/// What opening a pair gives: the volumes, the document on them, and for a session where its views looked.
#[derive(Debug)]
pub struct Opened {
    pub loaded: Loaded,
    pub document: Document,
    pub view: Option<session::View>,
}

/// A loaded pair and, when the window's device was known, both volumes prepared for it ([`LayerData::prepare`]), all
/// made on the loading thread.
#[derive(Debug)]
pub struct LoadedPair {
    pub opened: Opened,
    /// Fixed, moving.
    pub layers: Option<[LayerData; 2]>,
}

impl LoadedPair {
    /// Loads what `opts` names ([`load`]) and prepares both volumes for a device like `facts`.
    pub fn load(opts: &GuiOptions, watch: &Arc<open::Watch>, facts: Option<DeviceFacts>) -> anyhow::Result<Self> {
        let opened = load(opts, watch)?;
        let [fixed, moving] = [&opened.loaded.fixed, &opened.loaded.moving];
        let layers = match facts {
            Some(facts) => Some([LayerData::prepare(fixed, facts)?, LayerData::prepare(moving, facts)?]),
            None => None,
        };
        Ok(Self { opened, layers })
    }
}

/// Loads what `opts` names: a session, two volumes (with landmarks), or the demo pair when it names nothing,
/// reporting each file's progress to `watch` and stopping when it is cancelled.
pub fn load(opts: &GuiOptions, watch: &Arc<open::Watch>) -> anyhow::Result<Opened> {
    let read_part = |p: &std::path::Path, part: Option<&Part>| watch.load_options(p).part(part).open(p).map(Arc::new);
    let read = |p: &std::path::Path| read_part(p, None);
    let name =
        |p: &std::path::Path| p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into());
    if let Some(path) = &opts.session {
        let file = session::load(path)?;
        let Document { fixed, moving, fixed_part, moving_part, .. } = &file.document;
        let only_volumes = GuiOptions {
            fixed: fixed.clone(),
            moving: moving.clone(),
            parts: [fixed_part.clone(), moving_part.clone()],
            ..GuiOptions::default()
        };
        let mut opened = load(&only_volumes, watch)?;
        opened.loaded.title = format!("{} ({})", opened.loaded.title, name(path));
        opened.document = file.document;
        opened.document.clamp([&opened.loaded.fixed, &opened.loaded.moving]);
        opened.view = Some(file.view);
        return Ok(opened);
    }
    match (&opts.fixed, &opts.moving) {
        (Some(f), Some(m)) => {
            let [fixed_part, moving_part] = opts.parts.clone();
            let fixed = read_part(f, fixed_part.as_ref())?;
            let moving = read_part(m, moving_part.as_ref())?;
            let pairs = match &opts.landmarks {
                Some(source) => source.read().map_err(|e| anyhow!("{e:#}"))?,
                None => Vec::new(),
            };
            let mut document = Document::new([Some(f.clone()), Some(m.clone())], [&fixed, &moving], pairs);
            (document.fixed_part, document.moving_part) = (fixed_part, moving_part);
            let [f, m] = document.sources().map(|s| s.map(|s| s.name()).unwrap_or_default());
            Ok(Opened { loaded: Loaded { title: format!("{f} -> {m}"), fixed, moving }, document, view: None })
        }
        (None, None) => {
            let (title, fixed, moving) = if let Some((f, m)) = demo::demo_paths() {
                (format!("{} -> {} (demo)", name(&f), name(&m)), read(&f)?, read(&m)?)
            } else {
                let fixed = Arc::new(demo::phantom(96, 2.0, [0.0; 3], true));
                let moving = Arc::new(demo::phantom(96, 2.0, [6.0, -4.0, 3.0], false));
                ("phantom CT -> phantom MR (demo)".to_owned(), fixed, moving)
            };
            let pairs = demo::demo_landmarks(&fixed, &moving);
            let document = Document::new([None, None], [&fixed, &moving], pairs);
            Ok(Opened { loaded: Loaded { fixed, moving, title }, document, view: None })
        }
        _ => Err(anyhow!("give both a fixed and a moving volume, or neither for the demo pair")),
    }
}
