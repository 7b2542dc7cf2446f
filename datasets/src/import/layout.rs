//! Where each supported set keeps its images and labels: lists the (image, label) pairs of
//! a source folder. Missing files are not checked here; the import reports them per item.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{DatasetError, Result};

/// A supported source layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceFormat {
    /// SegNet's CamVid: `<split>.txt` lists `<split>/X.jpg <split>annot/X.png` lines.
    Camvid,
    /// `leftImg8bit/<split>/<city>/X_leftImg8bit.png` and
    /// `gtFine/<split>/<city>/X_gtFine_labelIds.png` (or `_labelTrainIds.png`).
    Cityscapes,
    /// `<split>/images/X.jpg` and `<split>/<version>/labels/X.png`.
    Mapillary,
    /// Any folder pair matched by file stem: `--images` and `--labels` (CARLA renders, lane
    /// masks and plain folders use it).
    Folders,
}

/// One source image and its label file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourcePair {
    /// Item id (made valid for file names).
    pub id: String,
    pub image: PathBuf,
    pub label: PathBuf,
    pub split: Option<String>,
}

/// What to list.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayoutOptions {
    pub root: PathBuf,
    /// Splits to take; empty = every split the source has (layouts with splits).
    pub splits: Vec<String>,
    /// Folders layout: image and label folders.
    pub images: Option<PathBuf>,
    pub labels: Option<PathBuf>,
    /// Cityscapes: `labelIds` or `labelTrainIds`; Mapillary: `v1.2` or `v2.0`.
    pub variant: Option<String>,
}

/// An id made of the characters manifests allow (others become `_`).
pub fn sanitize_id(stem: &str) -> String {
    let s: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    s.trim_start_matches('.').to_owned()
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Files of a folder, sorted by name (hidden files left out).
fn sorted_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| DatasetError::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| DatasetError::io(dir, e))?;
        let path = entry.path();
        let hidden = entry.file_name().to_string_lossy().starts_with('.');
        if path.is_file() && !hidden {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// Sub-folders of a folder, sorted.
fn sorted_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| DatasetError::io(dir, e))?;
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    Ok(dirs)
}

fn is_image_file(path: &Path) -> bool {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    matches!(
        ext.as_str(),
        "png" | "jpg" | "jpeg" | "bmp" | "tif" | "tiff" | "webp"
    )
}

/// Lists the pairs of a source, sorted by id; two pairs with one id are an error.
pub fn list_pairs(format: SourceFormat, opts: &LayoutOptions) -> Result<Vec<SourcePair>> {
    if !opts.root.is_dir() {
        return Err(DatasetError::invalid(&opts.root, "is not a folder"));
    }
    let mut pairs = match format {
        SourceFormat::Camvid => camvid(opts)?,
        SourceFormat::Cityscapes => cityscapes(opts)?,
        SourceFormat::Mapillary => mapillary(opts)?,
        SourceFormat::Folders => folders(opts)?,
    };
    pairs.sort_by(|a, b| a.id.cmp(&b.id));
    for w in pairs.windows(2) {
        if w[0].id == w[1].id {
            return Err(DatasetError::invalid(
                &w[1].image,
                format!(
                    "gives item id `{}` a second time (also {})",
                    w[1].id,
                    w[0].image.display()
                ),
            ));
        }
    }
    if pairs.is_empty() {
        return Err(DatasetError::invalid(
            &opts.root,
            "holds no image/label pairs in the expected layout",
        ));
    }
    Ok(pairs)
}

fn splits_or(opts: &LayoutOptions, default: &[&str]) -> Vec<String> {
    if opts.splits.is_empty() {
        default.iter().map(|s| (*s).to_owned()).collect()
    } else {
        opts.splits.clone()
    }
}

fn camvid(opts: &LayoutOptions) -> Result<Vec<SourcePair>> {
    let mut splits = splits_or(opts, &[]);
    if splits.is_empty() {
        splits = ["train", "val", "test"]
            .into_iter()
            .filter(|s| opts.root.join(format!("{s}.txt")).is_file())
            .map(str::to_owned)
            .collect();
    }
    let mut pairs = Vec::new();
    for split in splits {
        let list = opts.root.join(format!("{split}.txt"));
        let text = std::fs::read_to_string(&list).map_err(|e| DatasetError::io(&list, e))?;
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split_whitespace().collect();
            let [image, label] = fields.as_slice() else {
                return Err(DatasetError::Line {
                    path: list.clone(),
                    line: i + 1,
                    message: "expected `<image> <label>`".into(),
                });
            };
            // SegNet's lists name files as /SegNet/CamVid/<split>/X.png: keep the last two parts.
            let local = |p: &str| {
                let parts: Vec<&str> = p.split('/').filter(|s| !s.is_empty()).collect();
                let n = parts.len();
                opts.root.join(parts[n.saturating_sub(2)..].join("/"))
            };
            let image = local(image);
            pairs.push(SourcePair {
                id: sanitize_id(&stem(&image)),
                label: local(label),
                image,
                split: Some(split.clone()),
            });
        }
    }
    Ok(pairs)
}

fn cityscapes(opts: &LayoutOptions) -> Result<Vec<SourcePair>> {
    let suffix = opts.variant.as_deref().unwrap_or("labelIds");
    let mut pairs = Vec::new();
    for split in splits_or(opts, &["train", "val"]) {
        let image_root = opts.root.join("leftImg8bit").join(&split);
        if !image_root.is_dir() {
            if opts.splits.is_empty() {
                continue;
            }
            return Err(DatasetError::invalid(&image_root, "is not a folder"));
        }
        for city in sorted_dirs(&image_root)? {
            for image in sorted_files(&city)? {
                let name = stem(&image);
                let Some(base) = name.strip_suffix("_leftImg8bit") else {
                    continue;
                };
                let city_name = city.file_name().unwrap_or_default();
                let label = opts
                    .root
                    .join("gtFine")
                    .join(&split)
                    .join(city_name)
                    .join(format!("{base}_gtFine_{suffix}.png"));
                pairs.push(SourcePair {
                    id: sanitize_id(base),
                    image,
                    label,
                    split: Some(split.clone()),
                });
            }
        }
    }
    Ok(pairs)
}

fn mapillary(opts: &LayoutOptions) -> Result<Vec<SourcePair>> {
    let version = opts.variant.as_deref().unwrap_or("v1.2");
    let mut pairs = Vec::new();
    for split in splits_or(opts, &["training", "validation"]) {
        let images = opts.root.join(&split).join("images");
        if !images.is_dir() {
            if opts.splits.is_empty() {
                continue;
            }
            return Err(DatasetError::invalid(&images, "is not a folder"));
        }
        for image in sorted_files(&images)?
            .into_iter()
            .filter(|p| is_image_file(p))
        {
            let name = stem(&image);
            let label = opts
                .root
                .join(&split)
                .join(version)
                .join("labels")
                .join(format!("{name}.png"));
            pairs.push(SourcePair {
                id: sanitize_id(&name),
                image,
                label,
                split: Some(split.clone()),
            });
        }
    }
    Ok(pairs)
}

fn folders(opts: &LayoutOptions) -> Result<Vec<SourcePair>> {
    let images = opts
        .images
        .clone()
        .unwrap_or_else(|| opts.root.join("images"));
    let labels = opts
        .labels
        .clone()
        .unwrap_or_else(|| opts.root.join("labels"));
    if !images.is_dir() {
        return Err(DatasetError::invalid(&images, "is not an image folder"));
    }
    if !labels.is_dir() {
        return Err(DatasetError::invalid(&labels, "is not a label folder"));
    }
    // Labels by file stem (the first in name order where two share one); each image takes
    // its own, and what is left over has no image.
    let mut labels_by_stem: std::collections::BTreeMap<String, PathBuf> = sorted_files(&labels)?
        .into_iter()
        .rev()
        .filter(|p| is_image_file(p))
        .map(|p| (stem(&p), p))
        .collect();
    let mut pairs = Vec::new();
    for image in sorted_files(&images)?
        .into_iter()
        .filter(|p| is_image_file(p))
    {
        let name = stem(&image);
        let label = labels_by_stem
            .remove(&name)
            .unwrap_or_else(|| labels.join(format!("{name}.png")));
        pairs.push(SourcePair {
            id: sanitize_id(&name),
            image,
            label,
            split: None,
        });
    }
    // A label without an image is a broken item, not one to drop silently: it is listed
    // with the image path it lacks, so the import reports it (error or counted skip).
    for (name, label) in labels_by_stem {
        pairs.push(SourcePair {
            id: sanitize_id(&name),
            image: images.join(&name),
            label,
            split: None,
        });
    }
    pairs.sort_by(|a, b| a.id.cmp(&b.id));
    Ok(pairs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_made_valid() {
        assert_eq!(sanitize_id("0016E5_07959"), "0016E5_07959");
        assert_eq!(sanitize_id(".a b/ü"), "a_b__");
    }

    #[test]
    fn folders_pair_by_stem() -> Result<()> {
        let dir = tempfile::tempdir().map_err(|e| DatasetError::io(Path::new("tmp"), e))?;
        for f in [
            "images/b.jpg",
            "images/a.png",
            "images/notes.txt",
            "labels/a.png",
            "labels/b.png",
        ] {
            crate::image_io::write_bytes(&dir.path().join(f), b"x")?;
        }
        let opts = LayoutOptions {
            root: dir.path().to_path_buf(),
            splits: vec![],
            images: None,
            labels: None,
            variant: None,
        };
        let pairs = list_pairs(SourceFormat::Folders, &opts)?;
        let ids: Vec<&str> = pairs.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(ids, ["a", "b"]);
        assert!(pairs[1].label.ends_with("labels/b.png"));
        Ok(())
    }
}
