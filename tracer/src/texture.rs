//! Texture images: decoding PPM (P3/P6) and PNG files under memory limits, and bilinear
//! lookup in linear light.
//!
//! Texture files are read as sRGB-encoded 8-bit RGB (16-bit and grey images are converted;
//! alpha is dropped). Texels stay encoded in memory (3 bytes each) and are decoded through a
//! 256-entry table at lookup, so a large texture costs what its file says, not four times
//! that. Where texture bytes come from is [`AssetSource`]'s business, not this module's.

use std::collections::HashMap;
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::DVec2;

use crate::math::{Color, floor};
use crate::shape::{SurfaceUv, Wrap};
use crate::srgb;

/// Caps on texture decoding, so a small file cannot expand into a huge allocation
/// (a "decompression bomb"), and many files cannot add up to one. Each is checked from the
/// image's header, before anything is decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureLimits {
    /// Largest width or height in texels.
    pub max_dimension: u32,
    /// Largest width × height.
    pub max_pixels: u64,
    /// Largest sum of width × height over all of a scene's textures. Every texel is kept (3
    /// bytes), so this bounds a scene's texture memory whatever the number of files: a small
    /// PNG of one colour can decode to gigabytes of texels.
    pub max_total_pixels: u64,
}

impl Default for TextureLimits {
    fn default() -> Self {
        TextureLimits {
            max_dimension: 16_384,
            max_pixels: 64 * 1024 * 1024,
            max_total_pixels: 128 * 1024 * 1024,
        }
    }
}

/// Largest texture file [`DirAssets`] reads (it reads regular files only: a name can name
/// `/dev/zero`, which has no end). 1 GiB is more than the largest texture the limits allow
/// takes in any format (an ASCII PPM of 2²⁶ 16-bit texels passes it only with padding no
/// writer adds).
pub const MAX_TEXTURE_FILE_BYTES: u64 = 1 << 30;

/// Why a texture could not be used.
#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    /// The file cannot be read (or the assets do not hold it).
    #[error("cannot read texture file `{name}`: {reason}")]
    Missing {
        /// The texture name as the scene writes it.
        name: String,
        /// Why, as the operating system or the asset source says it.
        reason: String,
    },
    /// The bytes are neither a PNG nor a PPM.
    #[error("texture `{name}` is not a PNG or PPM (P3/P6) image")]
    UnknownFormat {
        /// The texture name as the scene writes it.
        name: String,
    },
    /// Wider, higher or larger than [`TextureLimits`] allow, by its header.
    #[error("texture `{name}` is {width}×{height} texels; the limit is {limit}")]
    TooLarge {
        /// The texture name as the scene writes it.
        name: String,
        /// Its width in texels.
        width: u32,
        /// Its height in texels.
        height: u32,
        /// The limit it passes, as a message shows it.
        limit: String,
    },
    #[error(
        "texture `{name}` ({texels} texels) brings the scene's textures to {total} texels; \
         the limit is {limit} in all"
    )]
    /// Within its own limits, but the scene's textures together pass
    /// [`TextureLimits::max_total_pixels`].
    TooMuch {
        /// The texture name as the scene writes it.
        name: String,
        /// Its own texels.
        texels: u64,
        /// The scene's texels with this one.
        total: u64,
        /// The limit on all of them.
        limit: u64,
    },
    /// The decoder would need more memory than the texture's limits allow.
    #[error("texture `{name}` needs more memory to decode than its limit allows ({limit})")]
    DecodeLimit {
        /// The texture name as the scene writes it.
        name: String,
        /// The limit, as a message shows it.
        limit: String,
    },
    /// The image's data is broken.
    #[error("texture `{name}` cannot be decoded: {reason}")]
    Decode {
        /// The texture name as the scene writes it.
        name: String,
        /// The decoder's message.
        reason: String,
    },
}

/// Where a scene's texture files come from.
pub trait AssetSource {
    /// The bytes of the asset the scene calls `name`.
    fn load(&self, name: &str) -> Result<Vec<u8>, TextureError>;
}

/// Assets held in memory by name (uploaded with a job, or fetched by a worker). Only these
/// names resolve; nothing touches the file system.
#[derive(Debug, Clone, Default)]
pub struct MemoryAssets {
    files: HashMap<String, Vec<u8>>,
}

impl MemoryAssets {
    /// No assets.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds (or replaces) the file `name` with `bytes`.
    pub fn insert(&mut self, name: impl Into<String>, bytes: Vec<u8>) {
        self.files.insert(name.into(), bytes);
    }

    /// Whether the assets hold a file `name`.
    pub fn contains(&self, name: &str) -> bool {
        self.files.contains_key(name)
    }
}

impl AssetSource for MemoryAssets {
    fn load(&self, name: &str) -> Result<Vec<u8>, TextureError> {
        self.files
            .get(name)
            .cloned()
            .ok_or_else(|| TextureError::Missing {
                name: name.to_string(),
                reason: "no asset with that name was provided".into(),
            })
    }
}

/// Assets read from files relative to a directory (the scene file's, for the local CLI).
#[derive(Debug, Clone)]
pub struct DirAssets {
    root: PathBuf,
}

impl DirAssets {
    /// Texture names are read relative to `root` (the scene file's folder).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        DirAssets { root: root.into() }
    }

    /// The file a texture name is read from.
    pub fn path_of(&self, name: &str) -> PathBuf {
        self.root.join(lexical(name))
    }
}

/// `name` with `.` dropped and `..` taken back against the name's own folders, before the
/// file system sees it; the farm resolves a scene's texture names with it too: `maps/../globe.png` is
/// `globe.png` whether or not `maps/` exists (or is a link elsewhere), so a scene that
/// renders on the farm renders here too. A `..` with no folder of the name's own before it
/// is kept (a local scene may reach outside its folder; the farm refuses that).
pub fn lexical(name: &str) -> PathBuf {
    use std::path::Component;
    let mut parts: Vec<Component> = Vec::new();
    for c in Path::new(name).components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(parts.last(), Some(Component::Normal(_))) => {
                parts.pop();
            }
            other => parts.push(other),
        }
    }
    parts.iter().collect()
}

impl AssetSource for DirAssets {
    fn load(&self, name: &str) -> Result<Vec<u8>, TextureError> {
        // `.`, `a/..`: the scene's own folder, which the file system would be asked for as
        // an empty path ("cannot read texture file `.`: : No such file or directory").
        if lexical(name).as_os_str().is_empty() {
            return Err(TextureError::Missing {
                name: name.to_string(),
                reason: "it names the scene's own folder, not a file".to_string(),
            });
        }
        let path = self.path_of(name);
        let missing = |reason: String| TextureError::Missing {
            name: name.to_string(),
            reason: format!("{}: {reason}", path.display()),
        };
        // Asked before opening too: opening a named pipe waits for a writer, for ever if none
        // comes. The open file is asked again below, in case the path changed meanwhile.
        let before = std::fs::metadata(&path).map_err(|e| missing(e.to_string()))?;
        if !before.is_file() {
            return Err(missing("not a regular file".to_string()));
        }
        let file = std::fs::File::open(&path).map_err(|e| missing(e.to_string()))?;
        let meta = file.metadata().map_err(|e| missing(e.to_string()))?;
        if !meta.is_file() {
            // A device or a pipe: `/dev/zero` would be read until memory ran out.
            return Err(missing("not a regular file".to_string()));
        }
        if meta.len() > MAX_TEXTURE_FILE_BYTES {
            return Err(missing(format!(
                "{} bytes; a texture file may have at most {MAX_TEXTURE_FILE_BYTES}",
                meta.len()
            )));
        }
        // Bounded again while reading, for a file that grows meanwhile.
        let mut bytes = Vec::new();
        file.take(MAX_TEXTURE_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| missing(e.to_string()))?;
        if bytes.len() as u64 > MAX_TEXTURE_FILE_BYTES {
            return Err(missing(format!(
                "more than {MAX_TEXTURE_FILE_BYTES} bytes, the most a texture file may have"
            )));
        }
        Ok(bytes)
    }
}

/// A decoded texture: sRGB-encoded RGB8 texels, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    width: u32,
    height: u32,
    texels: Vec<[u8; 3]>,
}

fn decode_lut() -> &'static [f32; 256] {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(srgb::decode_table)
}

/// A reader for PNG or PPM bytes, its format known; anything else is refused.
fn reader<'a>(
    name: &str,
    bytes: &'a [u8],
) -> Result<image::ImageReader<Cursor<&'a [u8]>>, TextureError> {
    let reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| decode_error(name, e))?;
    match reader.format() {
        Some(image::ImageFormat::Png | image::ImageFormat::Pnm) => Ok(reader),
        _ => Err(TextureError::UnknownFormat {
            name: name.to_string(),
        }),
    }
}

fn decode_error(name: &str, e: impl std::fmt::Display) -> TextureError {
    TextureError::Decode {
        name: name.to_string(),
        reason: e.to_string(),
    }
}

impl Texture {
    /// The image's width and height, read from its header alone (nothing is decoded), and
    /// checked against `limits`: a bad or oversized image is refused here, whatever its
    /// pixel data, before anything is allocated for them.
    pub fn dimensions(
        name: &str,
        bytes: &[u8],
        limits: &TextureLimits,
    ) -> Result<(u32, u32), TextureError> {
        let (w, h) = reader(name, bytes)?
            .into_dimensions()
            .map_err(|e| decode_error(name, e))?;
        if w == 0 || h == 0 {
            return Err(decode_error(name, format_args!("the image is {w}×{h}")));
        }
        if w.max(h) > limits.max_dimension || u64::from(w) * u64::from(h) > limits.max_pixels {
            return Err(TextureError::TooLarge {
                name: name.to_string(),
                width: w,
                height: h,
                limit: format!(
                    "{} texels a side and {} in all",
                    limits.max_dimension, limits.max_pixels
                ),
            });
        }
        Ok((w, h))
    }

    /// Decodes PNG or PPM bytes, refusing images beyond `limits` (from the header, see
    /// [`Self::dimensions`]) before allocating them.
    pub fn decode(
        name: &str,
        bytes: &[u8],
        limits: &TextureLimits,
    ) -> Result<Texture, TextureError> {
        let size = Self::dimensions(name, bytes, limits)?;
        Self::decode_sized(name, bytes, limits, size)
    }

    /// [`Self::decode`] for a caller that has the size from [`Self::dimensions`] already
    /// (the scene's texture budget needs it before decoding), so the header is read once.
    pub(crate) fn decode_sized(
        name: &str,
        bytes: &[u8],
        limits: &TextureLimits,
        (w, h): (u32, u32),
    ) -> Result<Texture, TextureError> {
        let mut reader = reader(name, bytes)?;
        let mut decoder_limits = image::Limits::default();
        decoder_limits.max_image_width = Some(limits.max_dimension);
        decoder_limits.max_image_height = Some(limits.max_dimension);
        // Room for the decoded image at 16-bit RGBA plus the decoder's own buffers: the
        // header has been checked, so this only stops a decoder that wants far more.
        let max_alloc = u64::from(w) * u64::from(h) * 8 + (1 << 20);
        decoder_limits.max_alloc = Some(max_alloc);
        reader.limits(decoder_limits);
        let img = reader.decode().map_err(|e| match e {
            image::ImageError::Limits(_) => TextureError::DecodeLimit {
                name: name.to_string(),
                limit: format!("{max_alloc} bytes"),
            },
            other => decode_error(name, other),
        })?;
        if (img.width(), img.height()) != (w, h) {
            return Err(decode_error(
                name,
                format_args!(
                    "the header says {w}×{h}, the image is {}×{}",
                    img.width(),
                    img.height()
                ),
            ));
        }
        let rgb = img.into_rgb8();
        let texels = rgb.pixels().map(|p| p.0).collect();
        Ok(Texture {
            width: w,
            height: h,
            texels,
        })
    }

    /// A texture from encoded texels, row-major from the top row.
    pub fn from_texels(width: u32, height: u32, texels: Vec<[u8; 3]>) -> Option<Texture> {
        (width > 0 && height > 0 && texels.len() == width as usize * height as usize).then_some(
            Texture {
                width,
                height,
                texels,
            },
        )
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    fn texel(&self, x: i64, y: i64) -> Color {
        let lut = decode_lut();
        // Callers pass coordinates already wrapped or clamped into range.
        let t = self.texels[y as usize * self.width as usize + x as usize];
        Color::new(
            f64::from(lut[t[0] as usize]),
            f64::from(lut[t[1] as usize]),
            f64::from(lut[t[2] as usize]),
        )
    }

    /// Bilinear lookup in linear light. `v = 0` is the bottom row of the image, `v = 1` the
    /// top; texel centres sit at half-integer coordinates.
    pub fn sample(&self, at: SurfaceUv) -> Color {
        let DVec2 { x: u, y: v } = at.uv;
        // A NaN coordinate (from a degenerate hit) reads the first texel rather than
        // poisoning the pixel.
        let (u, v) = (
            if u.is_finite() { u } else { 0.0 },
            if v.is_finite() { v } else { 0.0 },
        );
        let fx = u * f64::from(self.width) - 0.5;
        let fy = (1.0 - v) * f64::from(self.height) - 0.5;
        let (x0, y0) = (floor(fx), floor(fy));
        let (ax, ay) = (fx - x0, fy - y0);
        let xs = [
            wrap(x0 as i64, self.width, at.wrap_u),
            wrap((x0 as i64).saturating_add(1), self.width, at.wrap_u),
        ];
        let ys = [
            wrap(y0 as i64, self.height, at.wrap_v),
            wrap((y0 as i64).saturating_add(1), self.height, at.wrap_v),
        ];
        let top = self.texel(xs[0], ys[0]) * (1.0 - ax) + self.texel(xs[1], ys[0]) * ax;
        let bottom = self.texel(xs[0], ys[1]) * (1.0 - ax) + self.texel(xs[1], ys[1]) * ax;
        top * (1.0 - ay) + bottom * ay
    }
}

/// Brings a texel index into `0..n` by the wrap mode. Non-finite coordinates cast to
/// `i64::MIN`/`MAX`/0 and still land in range.
fn wrap(i: i64, n: u32, mode: Wrap) -> i64 {
    let n = i64::from(n);
    match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::Clamp => i.clamp(0, n - 1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uv(u: f64, v: f64) -> SurfaceUv {
        SurfaceUv {
            uv: DVec2::new(u, v),
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::Clamp,
        }
    }

    #[test]
    fn decodes_ascii_and_binary_ppm_and_png_alike() {
        let p3 = b"P3\n# a comment\n2 1\n255\n255 0 0  0 0 255\n";
        let mut p6 = b"P6\n2 1\n255\n".to_vec();
        p6.extend_from_slice(&[255, 0, 0, 0, 0, 255]);
        let mut png = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut png, 2, 1);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().expect("in-memory write");
            w.write_image_data(&[255, 0, 0, 0, 0, 255])
                .expect("in-memory write");
        }
        let l = TextureLimits::default();
        let a = Texture::decode("a.ppm", p3, &l).expect("P3");
        let b = Texture::decode("b.ppm", &p6, &l).expect("P6");
        let c = Texture::decode("c.png", &png, &l).expect("PNG");
        assert_eq!(a, b);
        assert_eq!(b, c);
        assert_eq!(a.texels, vec![[255, 0, 0], [0, 0, 255]]);
    }

    #[test]
    fn refuses_unknown_formats_and_oversized_images() {
        let l = TextureLimits {
            max_dimension: 4,
            max_pixels: 12,
            max_total_pixels: 100,
        };
        assert!(matches!(
            Texture::decode("x.gif", b"GIF89a....", &l),
            Err(TextureError::UnknownFormat { .. })
        ));
        // Headers that claim more than the limits, with no data behind them: refused as too
        // large, with the header's size, before any data is read (it would fail to decode).
        let too_large = |bytes: &[u8]| match Texture::decode("t.ppm", bytes, &l) {
            Err(TextureError::TooLarge { width, height, .. }) => (width, height),
            other => panic!("{other:?}"),
        };
        assert_eq!(too_large(b"P6\n100000 100000\n255\n"), (100_000, 100_000));
        // Over the side limit; over the texel limit with both sides within theirs.
        assert_eq!(too_large(b"P6\n5 1\n255\n"), (5, 1));
        assert_eq!(too_large(b"P6\n4 4\n255\n"), (4, 4));
        let at_limit = b"P3\n4 3\n255\n0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n";
        assert_eq!(
            Texture::dimensions("t.ppm", at_limit, &l).expect("within"),
            (4, 3)
        );
        assert!(Texture::decode("t.ppm", at_limit, &l).is_ok());
        // The message says the size.
        let e = Texture::decode("t.ppm", b"P6\n100000 7\n255\n", &l).expect_err("too wide");
        assert!(e.to_string().contains("100000×7 texels"), "{e}");
    }

    #[test]
    fn bilinear_lookup_hits_texel_centres_and_blends_between() {
        let t = Texture::from_texels(2, 1, vec![[255, 255, 255], [0, 0, 0]]).expect("2×1");
        assert!((t.sample(uv(0.25, 0.5)) - Color::ONE).length() < 1e-6);
        assert!(t.sample(uv(0.75, 0.5)).length() < 1e-6);
        let mid = t.sample(uv(0.5, 0.5));
        assert!((mid - Color::splat(0.5)).length() < 1e-6);
        // Repeat in u: just past the right edge blends back towards the first (white) texel.
        assert!((t.sample(uv(1.0, 0.5)) - Color::splat(0.5)).length() < 1e-6);
    }

    #[test]
    fn lookups_are_linear_light() {
        // sRGB code 188 is about 0.5 in linear light.
        let t = Texture::from_texels(1, 1, vec![[188, 188, 188]]).expect("1×1");
        let c = t.sample(uv(0.3, 0.3));
        assert!((c.x - 0.5).abs() < 0.005, "{c:?}");
    }

    #[test]
    fn non_finite_coordinates_stay_in_range() {
        let t = Texture::from_texels(2, 2, vec![[1, 2, 3]; 4]).expect("2×2");
        for x in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300] {
            let c = t.sample(uv(x, x));
            assert!(c.is_finite());
        }
    }

    #[test]
    fn memory_assets_resolve_only_their_own_names() {
        let mut a = MemoryAssets::new();
        a.insert("wood.png", vec![1, 2, 3]);
        assert_eq!(a.load("wood.png").expect("present"), vec![1, 2, 3]);
        assert!(a.load("../etc/passwd").is_err());
        assert!(a.load("/wood.png").is_err());
    }
}
