//! The octree artifact's packed walk: the CPU walk's copy of the tree (pc-tree's `Accel`,
//! docs/raytrace.md "The CPU walk's layout"), written by pc-octree beside the tree it copies so
//! that every later stage maps it instead of building it in memory (docs/artifacts.md, "The
//! packed walk").
//!
//! Five sections, all optional: an octree without them (written before they existed, or with
//! another [`LAYOUT`]) is walked through a copy built in memory, with the same hits. When
//! present and of this layout they are checked like every other section ([`WalkView::check`]):
//! every word, run and index the walk follows stays in bounds, so a walk over them cannot
//! index out of bounds whatever the file holds.

use bytemuck::{Pod, Zeroable};

use crate::octree::{node, BeginEnd, OctreeView};
use crate::reader::first_where;
use crate::Artifact;
use crate::ArtifactError;

/// Section names.
pub mod sections {
    pub const INFO: &str = "walk_info";
    pub const BLOCKS: &str = "walk_blocks";
    pub const LEAVES: &str = "walk_leaves";
    pub const CHUNKS: &str = "walk_chunks";
    pub const CLIPPED: &str = "walk_clipped";
}

/// Version of the records below and of what they mean; a reader of another layout builds its
/// own copy instead. 2: each chunk carries its lanes' data-pool indices, and `walk_clipped`
/// flags the splats with a border clip (1 kept the indices in a `walk_cold` section and had no
/// flags).
pub const LAYOUT: u32 = 2;

/// The [`WalkChunk::cold`] index of a padding lane.
pub const PADDING: u32 = u32::MAX;

/// Disks per [`WalkChunk`].
pub const LANES: usize = 4;

/// Words of a [`WalkBlock`]: an internal word points at its block's first word.
pub const BLOCK_WORDS: u32 = 16;

/// `walk_info`: one record.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct WalkInfo {
    /// [`LAYOUT`] of the writer.
    pub layout: u32,
    /// [`LANES`] of the writer.
    pub lanes: u32,
    /// 1: the blocks are a tree of [`WalkBlock`]s with node slabs; 0: `walk_blocks` holds the
    /// view's node pool word for word (leaf words rewritten), read as plain words.
    pub slabs: u32,
    pub _pad: u32,
}

/// One internal node's eight child words and the slab of every disk listed below it (one cache
/// line). Block 0 holds the root word alone. Child words: a leaf word's pointer is the leaf's
/// number in `walk_leaves`, an internal word's the first word of its children's block, an empty
/// word is the view's.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct WalkBlock {
    pub words: [u32; 8],
    /// The slab's axis, lo and hi as bits; `has_slab` 0 where it would not pay to test.
    pub slab: [u32; 5],
    pub has_slab: u32,
    pub _pad: [u32; 2],
}

/// One leaf: its run of chunks `first .. end`, the view's node word (what a hit reports) and
/// the slab `lo ≤ axis · x ≤ hi` (axis xyz, lo, hi) that holds its listed disks.
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct WalkLeaf {
    pub first: u32,
    pub end: u32,
    pub word: u32,
    pub slab: [f32; 5],
}

/// [`LANES`] listed disks, lane by lane: centre, normal, squared radius, and the data-pool
/// index of each (128 bytes, two cache lines). A padding lane has a zero normal, a negative
/// squared radius (no ray hits it) and the index [`PADDING`].
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct WalkChunk {
    pub px: [f32; LANES],
    pub py: [f32; LANES],
    pub pz: [f32; LANES],
    pub nx: [f32; LANES],
    pub ny: [f32; LANES],
    pub nz: [f32; LANES],
    pub r2: [f32; LANES],
    pub cold: [u32; LANES],
}

/// One bit per data-pool splat, set where the splat has a border clip (its record's `clip` is
/// not all zero; `walk_clipped`): a hit reads the splat's record to test the clip only where it
/// is set. Written after the splats' areas, which decide the clips. Stored, though the splats
/// give it, because making it reads every splat record (3.8 GB at the 100M-point scan's 59M
/// splats) and each stage that maps the walk would pay that at open.
pub fn clipped_bits(splats: &[crate::octree::Splat]) -> Vec<u64> {
    use rayon::prelude::*;
    splats
        .par_chunks(64)
        .map(|run| {
            run.iter()
                .enumerate()
                .fold(0u64, |w, (k, s)| w | u64::from(s.clip != [0.0; 4]) << k)
        })
        .collect()
}

/// Whether data-pool splat `i` is flagged in `bits` ([`clipped_bits`]).
#[inline(always)]
pub fn is_clipped(bits: &[u64], i: u32) -> bool {
    bits[i as usize / 64] >> (i % 64) & 1 != 0
}

/// The packed walk's sections, cast (checked by [`WalkView::check`] before any walk).
#[derive(Clone, Copy, Debug)]
pub struct WalkView<'a> {
    pub slabs: bool,
    pub blocks: &'a [WalkBlock],
    pub leaves: &'a [WalkLeaf],
    pub chunks: &'a [WalkChunk],
    /// [`clipped_bits`] of the data pool.
    pub clipped: &'a [u64],
}

impl<'a> WalkView<'a> {
    /// The sections of `a`, if it holds them in this [`LAYOUT`] (`None` otherwise: no walk, or
    /// another layout's). A section of the wrong element size is an error, as anywhere.
    pub(crate) fn sections(a: &'a Artifact) -> Result<Option<WalkView<'a>>, ArtifactError> {
        if !a.has_section(sections::INFO) {
            return Ok(None);
        }
        let info: &[WalkInfo] = a.section(sections::INFO)?;
        let Some(&info) = info.first() else {
            return Err(a.invalid("the `walk_info` section is empty"));
        };
        if info.layout != LAYOUT || info.lanes != LANES as u32 {
            return Ok(None);
        }
        Ok(Some(WalkView {
            slabs: info.slabs != 0,
            blocks: a.section(sections::BLOCKS)?,
            leaves: a.section(sections::LEAVES)?,
            chunks: a.section(sections::CHUNKS)?,
            clipped: a.section(sections::CLIPPED)?,
        }))
    }

    /// The `walk_info` record these sections carry.
    pub fn info(&self) -> WalkInfo {
        WalkInfo {
            layout: LAYOUT,
            lanes: LANES as u32,
            slabs: self.slabs as u32,
            _pad: 0,
        }
    }

    /// Structural checks against the tree they copy: the leaves are the view's, in its table
    /// order, each run within the chunks; every lane names a splat or is padding no ray hits;
    /// every child word the walk can follow stays within the blocks. What a check cannot see (a
    /// disk's coordinates) the checksums guard.
    pub fn check(&self, view: &OctreeView) -> Result<(), String> {
        // The leaves in table order, as the view lists them (its table checked already).
        let mut k = 0usize;
        for o in BeginEnd::offsets(view.begin_end) {
            let Some(l) = self.leaves.get(k) else {
                return Err(format!(
                    "walk_leaves has {} leaves; the tree has more",
                    self.leaves.len()
                ));
            };
            if l.word != node::leaf(o) {
                return Err(format!("walk leaf {k} is not the tree's leaf {k}"));
            }
            k += 1;
        }
        if k != self.leaves.len() {
            return Err(format!(
                "walk_leaves has {} leaves for the tree's {k}",
                self.leaves.len()
            ));
        }
        if let Some(i) = first_where(self.leaves, |_, l| {
            l.first > l.end || l.end as usize > self.chunks.len()
        }) {
            return Err(format!("walk leaf {i}'s run lies outside walk_chunks"));
        }
        let splats = view.splats.len();
        // Padding must be a lane no ray hits (a negative squared radius).
        let lane_ok = |c: &WalkChunk, l: usize| {
            (c.cold[l] as usize) < splats || (c.cold[l] == PADDING && c.r2[l] < 0.0)
        };
        if let Some(i) = first_where(self.chunks, |_, c| (0..LANES).any(|l| !lane_ok(c, l))) {
            let c = &self.chunks[i];
            let l = (0..LANES).find(|&l| !lane_ok(c, l)).unwrap_or(0);
            return Err(format!(
                "walk_chunks: chunk {i}, lane {l} names splat {} of {splats}",
                c.cold[l]
            ));
        }
        if self.clipped.len() != splats.div_ceil(64) {
            return Err(format!(
                "walk_clipped has {} words for {splats} splats",
                self.clipped.len()
            ));
        }
        self.check_words()
    }

    /// Every word the walk follows: leaf words name a leaf, internal words a whole block (or, in
    /// the flat layout, eight words) within the section.
    fn check_words(&self) -> Result<(), String> {
        let words: &[u32] = bytemuck::cast_slice(self.blocks);
        if words.is_empty() {
            return Err("walk_blocks is empty".into());
        }
        let span = if self.slabs { BLOCK_WORDS } else { 8 } as usize;
        let bad = |w: u32| {
            let p = node::ptr(w) as usize;
            if node::is_empty(w) {
                false
            } else if node::is_leaf(w) {
                p >= self.leaves.len()
            } else {
                p + span > words.len() || (self.slabs && !p.is_multiple_of(BLOCK_WORDS as usize))
            }
        };
        // The root word, then each block's eight child words (or every word, flat).
        let first_bad = if bad(words[0]) {
            Some((0, words[0]))
        } else if self.slabs {
            first_where(self.blocks, |b, blk| {
                b > 0 && blk.words.iter().any(|&w| bad(w))
            })
            .map(|b| {
                (
                    b,
                    *self.blocks[b].words.iter().find(|&&w| bad(w)).unwrap_or(&0),
                )
            })
        } else {
            first_where(words, |_, &w| bad(w)).map(|i| (i, words[i]))
        };
        if let Some((at, w)) = first_bad {
            return Err(format!(
                "walk_blocks word {w:#x} (block {at}) points outside"
            ));
        }
        Ok(())
    }
}

/// Write `walk`'s sections into an octree artifact being written: [`write_tree`], then
/// [`write_clipped`].
pub fn write(w: &mut crate::ArtifactWriter, walk: &WalkView) -> Result<(), ArtifactError> {
    write_tree(w, walk)?;
    write_clipped(w, walk.clipped)
}

/// The sections the tree alone decides (all but `walk_clipped`): pc-octree writes them while
/// it computes the splats' areas and clips.
pub fn write_tree(w: &mut crate::ArtifactWriter, walk: &WalkView) -> Result<(), ArtifactError> {
    w.section(sections::INFO, &[walk.info()])?;
    w.section(sections::BLOCKS, walk.blocks)?;
    w.section(sections::LEAVES, walk.leaves)?;
    w.section(sections::CHUNKS, walk.chunks)?;
    Ok(())
}

/// The `walk_clipped` section ([`clipped_bits`] of the finished splats).
pub fn write_clipped(w: &mut crate::ArtifactWriter, bits: &[u64]) -> Result<(), ArtifactError> {
    w.section(sections::CLIPPED, bits)
}
