//! An append-only log of CRC-checked records in NOR flash that survives a
//! power cut at any instant, on any [`NorFlash`] (`embedded-storage`).
//!
//! # Layout
//!
//! The log's range is `n` erase sectors. A record is a 20-byte header and its
//! payload, padded with 0xFF to the flash's write (and read) granularity:
//!
//! ```text
//! "PDBL"  format u16  len u16  generation u32  seq u32  crc32 u32  payload…
//! ```
//!
//! The CRC-32 (ISO-HDLC) covers the first 16 header bytes and the payload.
//! Records never straddle a sector. A *generation* is one run of records with
//! sequence numbers 0, 1, 2, … in consecutive sectors (wrapping at the end of
//! the range), starting at the first byte of its head sector; a sector is
//! erased right before the first record of a generation goes into it.
//!
//! # Why a power cut loses nothing that was written
//!
//! - A record counts only when its whole header and payload check out, so a
//!   torn write or a torn erase reads as "no record here".
//! - The live generation is the one with the highest number whose seq 0
//!   record is intact. A new generation ([`Log::start`]) goes into a sector
//!   *outside* the live one (a generation never uses more than `n - 1`
//!   sectors), so tearing its first erase or write leaves the previous
//!   generation exactly as it was.
//! - Reading stops at the first record that does not check out, then goes on
//!   at the next sector only if that sector opens with the expected sequence
//!   number of the same generation (or a lower one: see "Dropping a tail";
//!   or a rewrite of the record read last, past sectors whose head does
//!   not check out: see "A record that reads valid once").
//!   After a restore, and after any failed
//!   write, appending resumes at the next sector (the current one is
//!   *sealed*): a byte that a torn write may have touched is never written
//!   again before an erase, and no intact record ever follows a damaged one
//!   within a sector.
//! - A flash may report success for what did not take (bits that do not
//!   program in a worn sector, protect bits left set, a supply below the
//!   part's minimum; the RP2040's boot ROM reports nothing at all). So every
//!   record is read back after it is written, and every sector the log
//!   opens is read back erased (all 0xFF) before its first record: a
//!   mismatch is a failed write ([`LogError::Flash`]), handled as any other
//!   (the sector sealed, or opened again), and never acknowledged.
//!
//! # Dropping a tail
//!
//! A reader that finds a record it cannot use (a CRC-valid record that breaks
//! its grammar) keeps the records before it with [`Log::truncate`]: the
//! sectors after the one holding the first dropped record are erased, last
//! first, and that sector is sealed, so the next record opens the following
//! sector with the sequence number of the first dropped one. The rule that
//! makes this durable: **a sector that opens with record `j` of the
//! generation voids the records numbered `j` and up in the sector before
//! it** (all of them, when that one opens with `j` too: the run goes on
//! through it). Normally `j` is one past that sector's last record and voids
//! nothing. The drop is complete once a record follows; a cut before that
//! leaves the unusable record in place, and the next boot drops it again. A
//! cut while erasing leaves a shorter run of the same records (sectors are
//! erased last first, so none is left beyond a gap). The same rule makes a
//! write that failed yet landed harmless: its retry opens the next sector
//! with the same number and voids it.
//!
//! Erasing a dropped sector must not bring back what its head voided in
//! the sector before it (records an earlier drop left there, or a write
//! that failed yet landed). When the sectors from the first dropped one on
//! hold such records, the drop copies the kept records into a new
//! generation outside the live one instead, its record 0 written last:
//! until that write lands the old generation is live and whole, after it
//! the new one holds exactly the kept records (complete at once, no record
//! needs to follow). It costs a copy of the kept records, and it is refused
//! ([`LogError::Full`], nothing changed) when they do not fit beside the
//! live generation.
//!
//! # A record that reads valid once
//!
//! A cut in the middle of a program can leave cells just past the read
//! threshold: the record checks out at the next boot and fails at a later
//! one. Only the last write before a cut can be like that, so it is the
//! tail the boot finds; but a boot acknowledges it (the host sees the scan
//! it restored) and records follow it, and a walk that later stops at it
//! would lose them all. So a boot calls [`Log::settle`] once it restored:
//! the tail is written again, twice, at the head of a fresh sector (same
//! generation, number and CRC: the same bytes). The first copy voids the
//! original (the rule of "Dropping a tail"); the second, written after the
//! first returned in the same power-on, proves it whole, so a boot that
//! finds a record followed by its repeat in one sector has nothing to do
//! (a reset loop costs one sector, not one a boot). Reading passes over a
//! repeat of the record it read last, wherever it is; and where a sector's
//! head does not check out (a copy or an original that faded), reading
//! looks ahead to the next sector that opens with a record: it goes on
//! there if that record is the one expected or a repeat of the one read
//! last. No sector is passed over that could hold a live record: a record
//! after a head that does not check out was never read, and sectors past
//! the end of a generation are erased before it uses them. A generation of
//! one record cannot repeat record 0 in another sector (it would open the
//! generation twice), so it is copied into a new generation and repeated
//! there. What this does not cover: a record that fades although it was
//! written whole (that is a flash that loses data, see the end), and the
//! first record after a drop fading where its sector's head was all that
//! voided the dropped ones (a drop needs a damaged record to begin with).
//!
//! # Generation numbers never wrap into the past
//!
//! A new generation is numbered one more than the highest number at the
//! head of any sector. Only a damaged or adversarial image gets there, but a
//! CRC-valid record of generation `u32::MAX` would make the next number 0,
//! which every later scan would rank below it: the old scan would come back
//! after a reboot. So when the highest number is `u32::MAX`, [`Log::start`]
//! first erases every sector outside the live generation that opens with a
//! valid record (the live generation is untouched, so a cut here loses
//! nothing); the highest number is then the live generation's. If that is
//! `u32::MAX` itself, the new generation is numbered 0 and, once its first
//! record is durable, the live generation's head sector is erased: a cut
//! before that erase brings back the old generation (the start did not
//! complete), a cut after it the new one; its other sectors are erased by
//! the next start. Either way the numbers start again from the bottom.
//!
//! What it does not do: wear levelling beyond the rotation of generations
//! through the range, error correction (a bit that flips by itself in an old
//! record ends the log there), or more than `n - 1` sectors per generation.

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};

// The wire protocol's CRC-32 (one table in flash for both).
use crate::protocol::CRC;

/// Bytes of a record header.
pub const HEADER_LEN: usize = 20;
/// The largest payload a record can carry.
pub const MAX_PAYLOAD: usize = 1024;
/// Layout version this code writes in every header. 3: a record may be a
/// session boundary ([`super::Record::Session`]); 4: a session boundary may
/// carry the new session's camera ([`super::Record::SessionCamera`]), and a
/// resume is recorded ([`super::Record::Resumed`]); 5: decisions carry their
/// frame's key pool words ([`super::Record::Labels`]); the layout is that of 2.
pub const FORMAT: u16 = 5;
/// The oldest version still read: a log of 2 (written before sessions) is
/// read as it is, and a scan restored from it may be extended with records
/// of the current version. Records of any other version are not read (a
/// firmware of version 2 does not read a log of 3 or 4, so it never drops
/// the session records it does not know as unusable).
pub const OLDEST_FORMAT: u16 = 2;
/// The coarsest write or read granularity the log supports.
const MAX_ALIGN: usize = 32;
const MAGIC: [u8; 4] = *b"PDBL";

/// Why the log refused an operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum LogError {
    /// The flash reported an error.
    Flash(FlashErrorKind),
    /// The range is not whole sectors, has fewer than two, or the flash's
    /// granularity is not supported.
    BadRange,
    /// The payload is longer than [`MAX_PAYLOAD`] or than a sector holds.
    TooLarge,
    /// The generation has no sector left for the record.
    Full,
    /// No live generation to append to ([`Log::start`] one first).
    NotStarted,
    /// No record of the live generation at that place.
    NoRecord,
}

/// [`NorFlashErrorKind`] in a form that can be stored and compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FlashErrorKind {
    /// Offset or length not aligned to the flash's granularity.
    NotAligned,
    /// Outside the flash.
    OutOfBounds,
    /// Anything else the driver reported.
    Other,
}

impl<E: NorFlashError> From<E> for FlashErrorKind {
    fn from(e: E) -> Self {
        match e.kind() {
            NorFlashErrorKind::NotAligned => FlashErrorKind::NotAligned,
            NorFlashErrorKind::OutOfBounds => FlashErrorKind::OutOfBounds,
            _ => FlashErrorKind::Other,
        }
    }
}

fn flash_err<E: NorFlashError>(e: E) -> LogError {
    LogError::Flash(e.into())
}

/// A valid record header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Header {
    generation: u32,
    seq: u32,
    len: usize,
    crc: u32,
}

impl Header {
    /// Whether this record, found at the head of a sector, goes on with
    /// generation `generation` after `read` records, the last with CRC
    /// `last_crc`: it is the next one, or the rewrite of the last one (the
    /// same bytes: see "A record that reads valid once").
    fn goes_on(&self, generation: u32, read: u32, last_crc: u32) -> bool {
        self.generation == generation && (self.seq == read || self.repeats(read, last_crc))
    }

    /// Whether it is the rewrite of the record read last.
    fn repeats(&self, read: u32, last_crc: u32) -> bool {
        self.seq.wrapping_add(1) == read && self.crc == last_crc
    }
}

/// Where the live generation ends and the next record goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Live {
    generation: u32,
    /// Sector of seq 0.
    head: u32,
    /// Sectors in use, head included (at most `n - 1`).
    sectors: u32,
    /// Records in the generation; the next one's sequence number.
    records: u32,
    /// Write offset in the last sector in use; `None` when it is sealed and
    /// the next record opens a fresh sector.
    offset: Option<u32>,
}

/// A position in the live generation, for reading it record by record
/// ([`Log::next`]); [`Cursor::START`] is its first record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cursor {
    /// Sector, counted from the generation's head. (All fields start at 0:
    /// a device holding a cursor stays all zero bytes when new, in `.bss`.)
    sector: u32,
    /// Offset of the next record in the last of them.
    offset: u32,
    /// Records read; the next one's sequence number.
    records: u32,
    /// Records of this sector from this number on are void
    /// ([`Log::void_from`]), read when the sector was entered ...
    void_from: u32,
    /// ... while the live generation held this many records (an append may
    /// since have opened the next sector).
    void_checked: u32,
    /// CRC of the record read last, to know its rewrite.
    last_crc: u32,
}

impl Cursor {
    /// Moves past a record of `bytes` (aligned), into the next sector when
    /// it filled this one.
    fn pass(&mut self, bytes: u32, sector_len: u32) {
        self.offset += bytes;
        if self.offset >= sector_len {
            self.sector += 1;
            self.offset = 0;
        }
    }

    /// The first record of the live generation.
    pub const START: Cursor = Cursor {
        sector: 0,
        offset: 0,
        records: 0,
        void_from: 0,
        void_checked: 0,
        last_crc: 0,
    };

    /// Records before this position.
    pub fn records(&self) -> u32 {
        self.records
    }
}

/// The log over `flash`, in sectors `[start, start + n * ERASE_SIZE)`.
#[derive(Debug)]
pub struct Log<F> {
    flash: F,
    start: u32,
    sectors: u32,
    /// Bytes a record occupies are a multiple of this.
    align: usize,
    /// Highest generation number seen anywhere in the range.
    newest: u32,
    live: Option<Live>,
    /// Position of the tail record the last scan found, when no repeat of
    /// it follows it yet (see "A record that reads valid once").
    unsettled: Option<u32>,
    /// Where [`Log::settle`] put that record: (old position, new position),
    /// so that a position read before it still reads the record.
    moved: Option<(u32, u32)>,
    buf: [u8; HEADER_LEN + MAX_PAYLOAD + MAX_ALIGN],
}

/// The header of record `seq` of generation `generation` carrying `payload`
/// (at most [`MAX_PAYLOAD`] bytes).
pub(crate) fn header(generation: u32, seq: u32, payload: &[u8]) -> [u8; HEADER_LEN] {
    let len = (payload.len() as u16).to_le_bytes();
    let (g, s) = (generation.to_le_bytes(), seq.to_le_bytes());
    let [f0, f1] = FORMAT.to_le_bytes();
    let [m0, m1, m2, m3] = MAGIC;
    let mut head = [
        m0, m1, m2, m3, f0, f1, len[0], len[1], g[0], g[1], g[2], g[3], s[0], s[1], s[2], s[3], 0,
        0, 0, 0,
    ];
    let mut digest = CRC.digest();
    digest.update(head.get(..16).unwrap_or_default());
    digest.update(payload);
    let crc = digest.finalize().to_le_bytes();
    for (b, c) in head.iter_mut().skip(16).zip(crc) {
        *b = c;
    }
    head
}

fn align_up(n: usize, align: usize) -> usize {
    n.div_ceil(align).saturating_mul(align)
}

impl<F: NorFlash> Log<F> {
    /// Opens the log in `flash` bytes `start..end` (whole erase sectors, at
    /// least two) and finds its live generation, if any. Reads only.
    pub fn open(flash: F, start: u32, end: u32) -> Result<Self, LogError> {
        let sector = F::ERASE_SIZE;
        let align = F::WRITE_SIZE.max(F::READ_SIZE).max(4);
        let ok = sector > 0
            && align <= MAX_ALIGN
            && align.is_power_of_two()
            && sector.is_multiple_of(align)
            && sector >= align_up(HEADER_LEN + 64, align)
            && (start as usize).is_multiple_of(sector)
            && (end as usize).is_multiple_of(sector)
            && end > start
            && end as usize <= flash.capacity()
            && (end - start) as usize / sector >= 2;
        if !ok {
            return Err(LogError::BadRange);
        }
        let mut log = Log {
            flash,
            start,
            sectors: ((end - start) as usize / sector) as u32,
            align,
            newest: 0,
            live: None,
            unsettled: None,
            moved: None,
            buf: [0xFF; HEADER_LEN + MAX_PAYLOAD + MAX_ALIGN],
        };
        log.scan()?;
        Ok(log)
    }

    /// The flash, for a board that shares it.
    pub fn flash(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// Records in the live generation (0 when there is none).
    pub fn records(&self) -> u32 {
        self.live.map_or(0, |l| l.records)
    }

    /// Sectors the log spans.
    pub fn sector_count(&self) -> u32 {
        self.sectors
    }

    /// Sectors the live generation occupies.
    pub fn sectors_used(&self) -> u32 {
        self.live.map_or(0, |l| l.sectors)
    }

    /// Flash offset of the sector this log erases next: the one after the
    /// live generation, where its next sector or the next generation goes
    /// (the range's first sector without one). Never a sector of the live
    /// generation nor one whose first record voids any of its records
    /// (those are in the live generation), so erasing it early only does
    /// what the next erase here would do: see [`super::erase_ahead`].
    pub fn next_sector(&self) -> u32 {
        self.sector_offset(self.live.map_or(0, |l| l.head + l.sectors))
    }

    fn sector_len(&self) -> u32 {
        F::ERASE_SIZE as u32
    }

    fn sector_offset(&self, sector: u32) -> u32 {
        self.start + (sector % self.sectors) * self.sector_len()
    }

    /// Reads and checks the record at `sector`, `offset`; its payload is left
    /// in `buf[HEADER_LEN..]`.
    fn read_record(&mut self, sector: u32, offset: u32) -> Result<Option<Header>, LogError> {
        let sector_len = self.sector_len() as usize;
        let at = self.sector_offset(sector) + offset;
        let head_len = align_up(HEADER_LEN, self.align);
        if offset as usize + head_len > sector_len {
            return Ok(None);
        }
        let (head, _) = self.buf.split_at_mut(head_len);
        self.flash.read(at, head).map_err(flash_err)?;
        let field = |i: usize| self.buf.get(i..i + 4).and_then(|b| b.try_into().ok());
        let (Some(magic), Some(fl), Some(gen), Some(seq), Some(crc)) =
            (field(0), field(4), field(8), field(12), field(16))
        else {
            return Ok(None);
        };
        let [f0, f1, l0, l1] = fl;
        let len = usize::from(u16::from_le_bytes([l0, l1]));
        let total = align_up(HEADER_LEN + len, self.align);
        if magic != MAGIC
            || !(OLDEST_FORMAT..=FORMAT).contains(&u16::from_le_bytes([f0, f1]))
            || len > MAX_PAYLOAD
            || offset as usize + total > sector_len
        {
            return Ok(None);
        }
        if total > head_len {
            let rest = self
                .buf
                .get_mut(head_len..total)
                .ok_or(LogError::TooLarge)?;
            self.flash
                .read(at + head_len as u32, rest)
                .map_err(flash_err)?;
        }
        let mut digest = CRC.digest();
        digest.update(self.buf.get(..16).unwrap_or_default());
        digest.update(
            self.buf
                .get(HEADER_LEN..HEADER_LEN + len)
                .unwrap_or_default(),
        );
        if digest.finalize() != u32::from_le_bytes(crc) {
            return Ok(None);
        }
        Ok(Some(Header {
            generation: u32::from_le_bytes(gen),
            seq: u32::from_le_bytes(seq),
            len,
            crc: u32::from_le_bytes(crc),
        }))
    }

    /// Finds the newest generation number and the live generation's extent.
    fn scan(&mut self) -> Result<(), LogError> {
        let mut head: Option<(u32, u32)> = None; // (generation, sector)
        for s in 0..self.sectors {
            if let Some(h) = self.read_record(s, 0)? {
                self.newest = self.newest.max(h.generation);
                if h.seq == 0 && head.is_none_or(|(g, _)| h.generation > g) {
                    head = Some((h.generation, s));
                }
            }
        }
        let mut tail = None;
        let mut repeated = false;
        self.live = match head {
            Some((generation, head)) => {
                let visit = &mut |at, _: &[u8]| tail = Some(at);
                let (live, settled) = self.walk(generation, head, u32::MAX, visit)?;
                repeated = settled;
                Some(live)
            }
            None => None,
        };
        self.unsettled = tail.filter(|_| !repeated);
        self.moved = None;
        Ok(())
    }

    /// The sequence number from which the records of `sector`, the `used`-th
    /// sector of generation `generation`, are void: the number of the record
    /// that opens the next sector if that one can belong to the generation
    /// and does, else none (`u32::MAX`). See "Dropping a tail". Record 0
    /// voids nothing: it opens a generation, and no tail drop writes it.
    fn void_from(&mut self, generation: u32, sector: u32, used: u32) -> Result<u32, LogError> {
        if used.saturating_add(1) >= self.sectors {
            return Ok(u32::MAX);
        }
        let next = self.read_record(sector.wrapping_add(1), 0)?;
        Ok(next
            .filter(|h| h.generation == generation && h.seq > 0)
            .map_or(u32::MAX, |h| h.seq))
    }

    /// Follows generation `generation` from sector `head`, handing each of
    /// its first `limit` payloads to `visit`; returns its extent, sealed,
    /// and whether the last record read was followed by its repeat in the
    /// same sector (it is settled: see "A record that reads valid once").
    fn walk(
        &mut self,
        generation: u32,
        head: u32,
        limit: u32,
        visit: &mut dyn FnMut(u32, &[u8]),
    ) -> Result<(Live, bool), LogError> {
        let mut live = Live {
            generation,
            head,
            sectors: 1,
            records: 0,
            offset: None,
        };
        let sector_len = self.sector_len();
        let mut offset = 0u32;
        let mut void_from = u32::MAX;
        let mut last_crc = 0;
        let mut repeated = false;
        while live.records < limit {
            let sector = head + live.sectors - 1;
            if offset == 0 {
                void_from = self.void_from(generation, sector, live.sectors)?;
            }
            let found = self
                .read_record(sector, offset)?
                .filter(|h| h.generation == generation);
            match found {
                Some(h) if h.repeats(live.records, last_crc) => {
                    // A rewrite of the record read last: the same bytes.
                    // Right after it in its sector, it proves that record
                    // whole.
                    repeated = offset > 0;
                    offset += align_up(HEADER_LEN + h.len, self.align) as u32;
                    if offset < sector_len {
                        continue;
                    }
                }
                Some(h) if h.seq == live.records && h.seq < void_from => {
                    let at = self.position(sector, offset);
                    visit(
                        at,
                        self.buf
                            .get(HEADER_LEN..HEADER_LEN + h.len)
                            .unwrap_or_default(),
                    );
                    live.records += 1;
                    last_crc = h.crc;
                    repeated = false;
                    offset += align_up(HEADER_LEN + h.len, self.align) as u32;
                    if offset < sector_len {
                        continue;
                    }
                }
                // Void from here on (the whole sector, when a drop kept
                // none of it): the next sector goes on with this number.
                Some(h) if h.seq == live.records => {}
                _ if offset == 0 => {
                    // Sectors whose head does not check out are passed over
                    // when the next sector that opens with a record opens
                    // with the very record expected here, or a rewrite of
                    // the one read last (see "A record that reads valid
                    // once"). Otherwise this sector does not continue the
                    // generation.
                    if live.sectors > 1 {
                        let ahead = self.resumes(generation, sector, live, last_crc)?;
                        if let Some(k) = ahead {
                            live.sectors += k;
                            continue;
                        }
                    }
                    live.sectors -= 1;
                    return Ok((live, repeated));
                }
                _ => {}
            }
            if live.sectors + 1 >= self.sectors {
                return Ok((live, repeated));
            }
            live.sectors += 1;
            offset = 0;
        }
        Ok((live, repeated))
    }

    /// How many sectors after `sector` (the last of `live`, whose head does
    /// not check out) the generation goes on: the first sector after it
    /// that opens with a record opens with the one expected next, or a
    /// rewrite of the one read last (CRC `last_crc`). `None` when it does
    /// not, or only past the `n - 1` sectors a generation may use.
    fn resumes(
        &mut self,
        generation: u32,
        sector: u32,
        live: Live,
        last_crc: u32,
    ) -> Result<Option<u32>, LogError> {
        let mut k = 1;
        while live.sectors + k < self.sectors {
            if let Some(h) = self.read_record(sector + k, 0)? {
                return Ok(h.goes_on(generation, live.records, last_crc).then_some(k));
            }
            k += 1;
        }
        Ok(None)
    }

    /// Where record `offset` bytes into `sector` (counted from the range's
    /// first sector, any number of turns) is: bytes from the range's start.
    fn position(&self, sector: u32, offset: u32) -> u32 {
        (sector % self.sectors) * self.sector_len() + offset
    }

    /// Hands every payload of the live generation, in order, with its
    /// position (for [`Self::read_at`]), to `visit`.
    pub fn replay(&mut self, visit: &mut dyn FnMut(u32, &[u8])) -> Result<u32, LogError> {
        let Some(live) = self.live else {
            return Ok(0);
        };
        let (again, _) = self.walk(live.generation, live.head, live.records, visit)?;
        Ok(again.records)
    }

    /// Starts a new generation whose first record is `payload`; once this
    /// returns `Ok`, it is the live generation and the previous one is gone.
    /// On error the previous generation is still the live one. When the
    /// generation numbers have reached `u32::MAX` (a damaged or adversarial
    /// image), sectors outside the live generation are erased first and the
    /// numbers start again from 0 (see the module docs).
    pub fn start(&mut self, payload: &[u8]) -> Result<(), LogError> {
        if self.newest == u32::MAX {
            self.renumber()?;
        }
        let previous = self.live;
        // Still u32::MAX after renumbering: the live generation has it.
        let wraps = self.newest == u32::MAX;
        let head = match previous {
            Some(l) => (l.head + l.sectors) % self.sectors,
            None => 0,
        };
        let next = Live {
            generation: if wraps { 0 } else { self.newest + 1 },
            head,
            sectors: 0,
            records: 0,
            offset: None,
        };
        self.live = Some(next);
        if let Err(e) = self.append(payload) {
            self.live = previous;
            return Err(e);
        }
        if let (true, Some(old)) = (wraps, previous) {
            // Generation 0 ranks below the old one at scan until its head
            // record is gone. Its other sectors open with records of
            // sequence numbers > 0, which never make a head: the next start
            // erases them (`newest` stays u32::MAX until then).
            let at = self.sector_offset(old.head);
            if let Err(e) = self.flash.erase(at, at + self.sector_len()) {
                // The new head is in a sector outside the old generation,
                // which erases it before use; the next start renumbers.
                self.live = previous;
                return Err(flash_err(e));
            }
        }
        self.newest = self.newest.max(next.generation);
        (self.unsettled, self.moved) = (None, None);
        Ok(())
    }

    /// Erases every sector outside the live generation that opens with a
    /// valid record, so that the highest generation number at the head of a
    /// sector is the live generation's (0 without one). A cut at any step
    /// leaves the live generation as it was.
    fn renumber(&mut self) -> Result<(), LogError> {
        for s in 0..self.sectors {
            let in_live = self.live.is_some_and(|l| {
                (s + self.sectors - l.head % self.sectors) % self.sectors < l.sectors
            });
            if !in_live && self.read_record(s, 0)?.is_some() {
                let at = self.sector_offset(s);
                self.flash
                    .erase(at, at + self.sector_len())
                    .map_err(flash_err)?;
            }
        }
        self.newest = self.live.map_or(0, |l| l.generation);
        Ok(())
    }

    /// The payload of the live generation's record at position `at` (as
    /// [`Self::append`] and [`Self::replay`] give it).
    pub fn read_at(&mut self, at: u32) -> Result<&[u8], LogError> {
        let live = self.live.ok_or(LogError::NotStarted)?;
        let at = match self.moved {
            Some((old, new)) if old == at => new,
            _ => at,
        };
        let (sector, offset) = (at / self.sector_len(), at % self.sector_len());
        if sector >= self.sectors {
            return Err(LogError::NoRecord);
        }
        match self.read_record(sector, offset)? {
            Some(h) if h.generation == live.generation && h.seq < live.records => self
                .buf
                .get(HEADER_LEN..HEADER_LEN + h.len)
                .ok_or(LogError::NoRecord),
            _ => Err(LogError::NoRecord),
        }
    }

    /// The live generation's record at `cursor` and its position, moving
    /// the cursor past it; `None` after the last record.
    pub fn next(&mut self, cursor: &mut Cursor) -> Result<Option<(u32, &[u8])>, LogError> {
        let Some(live) = self.live else {
            return Ok(None);
        };
        let sector_len = self.sector_len();
        while cursor.records < live.records && cursor.sector < live.sectors {
            let sector = live.head + cursor.sector;
            if cursor.offset == 0 || cursor.void_checked != live.records {
                cursor.void_from = self.void_from(live.generation, sector, cursor.sector + 1)?;
                cursor.void_checked = live.records;
            }
            let found = self
                .read_record(sector, cursor.offset)?
                .filter(|h| h.generation == live.generation);
            if let Some(h) = found.filter(|h| h.repeats(cursor.records, cursor.last_crc)) {
                // A rewrite of the record this cursor read last (see "A
                // record that reads valid once"): the same bytes, read.
                cursor.pass(align_up(HEADER_LEN + h.len, self.align) as u32, sector_len);
                continue;
            }
            let found = found.filter(|h| h.seq == cursor.records && h.seq < cursor.void_from);
            let Some(h) = found else {
                // The rest of this sector is not the generation's: on to the next.
                cursor.sector += 1;
                cursor.offset = 0;
                continue;
            };
            let at = self.position(sector, cursor.offset);
            cursor.records += 1;
            cursor.last_crc = h.crc;
            cursor.pass(align_up(HEADER_LEN + h.len, self.align) as u32, sector_len);
            let payload = self.buf.get(HEADER_LEN..HEADER_LEN + h.len);
            return payload.map(|p| Some((at, p))).ok_or(LogError::NoRecord);
        }
        Ok(None)
    }

    /// Keeps the first `keep` records of the live generation and drops the
    /// rest (see "Dropping a tail"): the sectors after the one that holds
    /// record `keep` (the first dropped) are erased, last first, and that
    /// one is sealed, so that the next record, numbered `keep`, opens the
    /// following sector and voids record `keep` and what follows it there.
    /// That sector is not erased: it may open with record `keep` after
    /// records of the sector before it that it voids (an earlier drop, or a
    /// write that failed yet landed), which must stay void. Dropping nothing
    /// is a no-op; `keep` 0 (nothing to keep: start a new generation
    /// instead) and more records than there are are [`LogError::NoRecord`].
    /// Where erasing would bring back records voided before, the kept
    /// records are copied into a new generation instead (see "Dropping a
    /// tail"); [`LogError::Full`] when that copy does not fit.
    /// On a flash error the log is read again from the flash.
    pub fn truncate(&mut self, keep: u32) -> Result<(), LogError> {
        let live = self.live.ok_or(LogError::NotStarted)?;
        if keep == 0 || keep > live.records {
            return Err(LogError::NoRecord);
        }
        if keep == live.records {
            return Ok(());
        }
        let mut cursor = Cursor::START;
        for _ in 0..keep {
            self.next(&mut cursor)?.ok_or(LogError::NoRecord)?;
        }
        let (first_dropped, _) = self.next(&mut cursor)?.ok_or(LogError::NoRecord)?;
        let sector = first_dropped / self.sector_len();
        let kept_sectors = (sector + self.sectors - live.head % self.sectors) % self.sectors + 1;
        if self.hides_records(live, kept_sectors - 1)? {
            return self.truncate_by_copy(live, keep);
        }
        for s in (kept_sectors..live.sectors).rev() {
            let at = self.sector_offset(live.head + s);
            if let Err(e) = self.flash.erase(at, at + self.sector_len()) {
                self.scan()?;
                return Err(flash_err(e));
            }
        }
        self.live = Some(Live {
            sectors: kept_sectors,
            records: keep,
            offset: None,
            ..live
        });
        // The kept tail was written before what was dropped: not the last
        // write a cut can have left weak.
        (self.unsettled, self.moved) = (None, None);
        Ok(())
    }

    /// Whether a sector of `live` from the `from`-th on (counted from its
    /// head) holds records that the head of the sector after it voids (left
    /// by an earlier drop, or a write that failed yet landed): erasing that
    /// next sector would bring them back.
    fn hides_records(&mut self, live: Live, from: u32) -> Result<bool, LogError> {
        let sector_len = self.sector_len();
        for y in from..live.sectors.saturating_sub(1) {
            let next = self
                .read_record(live.head + y + 1, 0)?
                .filter(|h| h.generation == live.generation)
                .map_or(u32::MAX, |h| h.seq);
            // The records this sector holds, whether void or not.
            let (mut offset, mut end) = (0u32, None::<u32>);
            while offset < sector_len {
                let found = self
                    .read_record(live.head + y, offset)?
                    .filter(|h| h.generation == live.generation)
                    .filter(|h| end.is_none_or(|e| h.seq == e));
                let Some(h) = found else { break };
                end = Some(h.seq.saturating_add(1));
                offset += align_up(HEADER_LEN + h.len, self.align) as u32;
            }
            if end.is_some_and(|e| e > next) {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// [`Self::truncate`] where erasing the dropped sectors would bring back
    /// records voided before: the first `keep` records are copied into a new
    /// generation outside the live one, its head record written last, so
    /// that until that write lands the live generation is the old one,
    /// whole, and after it the new one, exactly the kept records (see
    /// "Dropping a tail"). [`LogError::Full`] (nothing changed) when the
    /// sectors outside the live generation cannot hold the copy.
    fn truncate_by_copy(&mut self, live: Live, keep: u32) -> Result<(), LogError> {
        if self.newest == u32::MAX {
            self.renumber()?;
        }
        let wraps = self.newest == u32::MAX;
        let generation = if wraps { 0 } else { self.newest + 1 };
        let sector_len = self.sector_len() as usize;
        let free = self.sectors.saturating_sub(live.sectors);
        // Where each record goes: (sector from the new head, offset), and
        // the extent; first without writing, to refuse before erasing.
        let place = |at: &mut (u32, usize), total: usize| {
            if at.1 + total > sector_len {
                *at = (at.0 + 1, 0);
            }
            let here = *at;
            at.1 += total;
            here
        };
        let mut at = (0u32, 0usize);
        let mut cursor = Cursor::START;
        for _ in 0..keep {
            let (_, p) = self.next(&mut cursor)?.ok_or(LogError::NoRecord)?;
            place(&mut at, align_up(HEADER_LEN + p.len(), self.align));
        }
        if at.0 + 1 > free {
            return Err(LogError::Full);
        }
        // A cut from here on may leave sectors of this number: never reuse it.
        if !wraps {
            self.newest = generation;
        }
        let head = live.head + live.sectors;
        let (mut at, mut cursor, mut erased) = ((0u32, 0usize), Cursor::START, None::<u32>);
        for seq in 0..keep {
            let len = self.next(&mut cursor)?.ok_or(LogError::NoRecord)?.1.len();
            let (sector, offset) = place(&mut at, align_up(HEADER_LEN + len, self.align));
            if erased != Some(sector) {
                let start = self.sector_offset(head + sector);
                self.flash
                    .erase(start, start + self.sector_len())
                    .map_err(flash_err)?;
                self.check_erased(start)?;
                erased = Some(sector);
            }
            if seq > 0 {
                self.write_copy(generation, seq, len, head + sector, offset)?;
            }
        }
        // The head record last: the new generation exists from this write on.
        let mut first = Cursor::START;
        let len = self.next(&mut first)?.ok_or(LogError::NoRecord)?.1.len();
        self.write_copy(generation, 0, len, head, 0)?;
        if wraps {
            // As in `start`: generation 0 ranks below the old one until its
            // head record is gone.
            let old = self.sector_offset(live.head);
            self.flash
                .erase(old, old + self.sector_len())
                .map_err(flash_err)?;
        }
        self.live = Some(Live {
            generation,
            head: head % self.sectors,
            sectors: at.0 + 1,
            records: keep,
            offset: Some(at.1 as u32),
        });
        (self.unsettled, self.moved) = (None, None);
        Ok(())
    }

    /// Writes the payload left in `buf` by the last read as record `seq` of
    /// `generation`, `offset` bytes into `sector`.
    fn write_copy(
        &mut self,
        generation: u32,
        seq: u32,
        len: usize,
        sector: u32,
        offset: usize,
    ) -> Result<(), LogError> {
        let total = align_up(HEADER_LEN + len, self.align);
        let at = self.sector_offset(sector) + offset as u32;
        let payload = self
            .buf
            .get(HEADER_LEN..HEADER_LEN + len)
            .ok_or(LogError::TooLarge)?;
        let head = header(generation, seq, payload);
        let record = self.buf.get_mut(..total).ok_or(LogError::TooLarge)?;
        for (b, v) in record.iter_mut().zip(head) {
            *b = v;
        }
        record
            .get_mut(HEADER_LEN + len..)
            .unwrap_or_default()
            .fill(0xFF);
        self.flash.write(at, record).map_err(flash_err)?;
        self.check_written(at, total)
    }

    /// Bytes the live generation occupies (whole sectors), and the most one
    /// generation can occupy (`n - 1` sectors).
    pub fn usage(&self) -> (u32, u32) {
        let sector = self.sector_len();
        let used = self.live.map_or(0, |l| l.sectors.saturating_mul(sector));
        (used, self.sectors.saturating_sub(1).saturating_mul(sector))
    }

    /// Appends one record to the live generation; `Ok` (with the record's
    /// position, for [`Self::read_at`]) means it is durable.
    pub fn append(&mut self, payload: &[u8]) -> Result<u32, LogError> {
        let total = align_up(HEADER_LEN + payload.len(), self.align);
        if payload.len() > MAX_PAYLOAD || total > self.sector_len() as usize {
            return Err(LogError::TooLarge);
        }
        let mut live = self.live.ok_or(LogError::NotStarted)?;
        let offset = match live.offset {
            Some(o) if o as usize + total <= self.sector_len() as usize => o,
            _ => {
                if live.sectors + 1 >= self.sectors {
                    return Err(LogError::Full);
                }
                let at = self.sector_offset(live.head + live.sectors);
                // Counted as used only once erased, and read back erased (a
                // flash may report success for an erase that did not
                // happen): the walk at restore stops at a sector that does
                // not open with the next record, so a sector that failed
                // must be retried, not skipped.
                self.flash
                    .erase(at, at + self.sector_len())
                    .map_err(flash_err)?;
                self.check_erased(at)?;
                live.sectors += 1;
                0
            }
        };
        let head = header(live.generation, live.records, payload);
        let at = self.sector_offset(live.head + live.sectors - 1) + offset;
        let record = self.buf.get_mut(..total).ok_or(LogError::TooLarge)?;
        record.fill(0xFF);
        for (b, v) in record.iter_mut().zip(head.iter().chain(payload)) {
            *b = *v;
        }
        let written = self
            .flash
            .write(at, record)
            .map_err(flash_err)
            .and_then(|()| self.check_written(at, total));
        if let Err(e) = written {
            // Bytes a failed write may have touched are never written again:
            // the sector is sealed, or erased again if this was its first
            // record (a sector that does not open with the next record ends
            // the generation at restore). A write that reported success but
            // reads back otherwise (bits that did not program, a protected
            // sector) is a failed write: never acknowledged.
            if offset == 0 {
                live.sectors -= 1;
            }
            live.offset = None;
            self.live = Some(live);
            return Err(e);
        }
        live.records += 1;
        live.offset = Some(offset + total as u32);
        self.live = Some(live);
        Ok(self.position(live.head + live.sectors - 1, offset))
    }

    /// Makes the tail record [`Self::open`] found whole before anything is
    /// acknowledged on it: a boot calls it once it has read the log (see "A
    /// record that reads valid once"); the position it read the record at
    /// still reads it ([`Self::read_at`]). The record is written twice at the head of
    /// a fresh sector (record 0: as a new generation, then again after it);
    /// nothing to do when its repeat follows it already. On error the live
    /// generation is as it was, and the log reads as before.
    pub fn settle(&mut self) -> Result<(), LogError> {
        let (Some(tail), Some(mut live)) = (self.unsettled, self.live) else {
            return Ok(());
        };
        if live.records <= 1 {
            // Record 0 opens its generation: no sector may repeat it there.
            self.truncate_by_copy(live, 1)?;
            live = self.live.ok_or(LogError::NotStarted)?;
            let len = self
                .read_record(live.head, 0)?
                .ok_or(LogError::Flash(FlashErrorKind::Other))?
                .len;
            let total = align_up(HEADER_LEN + len, self.align);
            if let Err(e) = self.write_copy(live.generation, 0, len, live.head, total) {
                // Bytes it may have touched are never written again; record
                // 0 is still to settle (by the next boot).
                self.live = Some(Live {
                    offset: None,
                    ..live
                });
                self.unsettled = Some(self.position(live.head, 0));
                return Err(e);
            }
            live.offset = Some(2 * total as u32);
            self.live = Some(live);
            self.moved = Some((tail, self.position(live.head, 0)));
            return Ok(());
        }
        let (sector, offset) = (tail / self.sector_len(), tail % self.sector_len());
        let len = self
            .read_record(sector, offset)?
            .filter(|h| h.generation == live.generation && h.seq.wrapping_add(1) == live.records)
            .ok_or(LogError::Flash(FlashErrorKind::Other))?
            .len;
        if live.sectors + 1 >= self.sectors {
            return Err(LogError::Full);
        }
        let fresh = live.head + live.sectors;
        let at = self.sector_offset(fresh);
        self.flash
            .erase(at, at + self.sector_len())
            .map_err(flash_err)?;
        self.check_erased(at)?;
        // The same bytes as the original (same generation and number),
        // twice: the second proves the first whole.
        let total = align_up(HEADER_LEN + len, self.align);
        self.write_copy(
            live.generation,
            live.records.saturating_sub(1),
            len,
            fresh,
            0,
        )?;
        self.write_copy(
            live.generation,
            live.records.saturating_sub(1),
            len,
            fresh,
            total,
        )?;
        live.sectors += 1;
        live.offset = Some(2 * total as u32);
        self.live = Some(live);
        self.unsettled = None;
        self.moved = Some((tail, self.position(fresh, 0)));
        Ok(())
    }

    /// Reads the sector at `at` back: an error unless every byte is 0xFF.
    fn check_erased(&mut self, at: u32) -> Result<(), LogError> {
        let mut chunk = [0u8; MAX_ALIGN];
        let step = MAX_ALIGN.max(self.align);
        for offset in (0..self.sector_len()).step_by(step) {
            let part = chunk.get_mut(..step).ok_or(LogError::BadRange)?;
            self.flash.read(at + offset, part).map_err(flash_err)?;
            if part.iter().any(|&b| b != 0xFF) {
                return Err(LogError::Flash(FlashErrorKind::Other));
            }
        }
        Ok(())
    }

    /// Reads the `len` bytes just written at `at` back: an error unless they
    /// are the record in `buf`.
    fn check_written(&mut self, at: u32, len: usize) -> Result<(), LogError> {
        let mut chunk = [0u8; MAX_ALIGN];
        let step = MAX_ALIGN.max(self.align);
        for offset in (0..len).step_by(step) {
            let n = step.min(len - offset);
            let part = chunk.get_mut(..n).ok_or(LogError::BadRange)?;
            self.flash
                .read(at + offset as u32, part)
                .map_err(flash_err)?;
            if self.buf.get(offset..offset + n) != Some(&*part) {
                return Err(LogError::Flash(FlashErrorKind::Other));
            }
        }
        Ok(())
    }

    /// Whether `count` more records of up to `len` payload bytes each are
    /// sure to fit in the live generation (or in a new one when none is live).
    pub fn has_room(&self, count: usize, len: usize) -> bool {
        let total = align_up(HEADER_LEN + len, self.align);
        let sector_len = self.sector_len() as usize;
        if len > MAX_PAYLOAD || total > sector_len {
            return false;
        }
        let per_sector = sector_len / total;
        let (free_sectors, in_current) = match self.live {
            Some(l) => (
                self.sectors.saturating_sub(1 + l.sectors),
                l.offset.map_or(0, |o| (sector_len - o as usize) / total),
            ),
            None => (self.sectors.saturating_sub(1), 0),
        };
        in_current + free_sectors as usize * per_sector >= count
    }

    /// [`Self::has_room`] for records of two lengths written in order:
    /// `first.0` records of up to `first.1` payload bytes, then `then.0` of
    /// up to `then.1` (a step's key chunks, then its shorter records). Exact
    /// for the records at those lengths, and a bound for shorter ones: a
    /// sector opens only when the next record does not fit the last one, so
    /// shorter records never end further on.
    pub fn has_room_then(&self, first: (usize, usize), then: (usize, usize)) -> bool {
        let sector_len = self.sector_len() as usize;
        let (mut free_sectors, mut left) = match self.live {
            Some(l) => (
                self.sectors.saturating_sub(1 + l.sectors) as usize,
                l.offset
                    .map_or(0, |o| sector_len.saturating_sub(o as usize)),
            ),
            None => (self.sectors.saturating_sub(1) as usize, 0),
        };
        for (count, len) in [first, then] {
            if count == 0 {
                continue;
            }
            let total = align_up(HEADER_LEN + len, self.align);
            if len > MAX_PAYLOAD || total > sector_len {
                return false;
            }
            let here = left / total;
            if here >= count {
                left -= count * total;
                continue;
            }
            // The rest opens new sectors, `per_sector` records each.
            let rest = count - here;
            let per_sector = sector_len / total;
            let sectors = rest.div_ceil(per_sector);
            if sectors > free_sectors {
                return false;
            }
            free_sectors -= sectors;
            left = sector_len - (rest - (sectors - 1) * per_sector) * total;
        }
        true
    }
}

#[cfg(all(test, feature = "sim-flash"))]
mod tests {
    extern crate std;
    use super::*;
    use crate::persist::sim::{SimFlash, Tear};
    use std::format;
    use std::vec;
    use std::vec::Vec;

    const SECTORS: usize = 4;

    /// The log over the whole of `flash`.
    fn open(flash: SimFlash) -> Log<SimFlash> {
        let end = flash.bytes().len() as u32;
        Log::open(flash, 0, end).unwrap()
    }

    /// Every payload of the live generation.
    fn payloads(log: &mut Log<SimFlash>) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        log.replay(&mut |_, p| out.push(p.to_vec())).unwrap();
        out
    }

    /// What a reboot finds: the live generation of the flash opened afresh.
    fn reboot(log: Log<SimFlash>) -> (Log<SimFlash>, Vec<Vec<u8>>) {
        let mut log = open(log.into_flash());
        let found = payloads(&mut log);
        (log, found)
    }

    /// A flash whose live generation, numbered `generation`, holds
    /// `records` records in sector `sector`, as an image may hold it.
    fn image(generation: u32, sector: usize, records: &[&[u8]]) -> SimFlash {
        let mut flash = SimFlash::new(SECTORS);
        let mut at = sector * SimFlash::SECTOR;
        for (seq, p) in records.iter().enumerate() {
            at += flash.put_record(at, generation, seq as u32, p).unwrap();
        }
        flash
    }

    fn owned(records: &[&[u8]]) -> Vec<Vec<u8>> {
        records.iter().map(|r| r.to_vec()).collect()
    }

    #[test]
    fn generations_go_on_past_the_wrap_point() {
        // Live generation u32::MAX - 1: the next is u32::MAX, then 0, 1, ...
        let mut log = open(image(u32::MAX - 1, 1, &[b"old", b"old 2"]));
        assert_eq!(payloads(&mut log), owned(&[b"old", b"old 2"]));
        for (i, payload) in [&b"max"[..], b"zero", b"one", b"two"].iter().enumerate() {
            log.start(payload).unwrap();
            log.append(b"more").unwrap();
            let (again, found) = reboot(log);
            assert_eq!(found, owned(&[payload, b"more"]), "start {i}");
            log = again;
        }
        // Numbering started again from the bottom: nothing of u32::MAX left.
        assert_eq!(log.newest, 2);
        assert_eq!(log.live.map(|l| l.generation), Some(2));
    }

    #[test]
    fn a_stale_sector_at_the_wrap_point_is_erased_not_outranking() {
        // Live generation 7 in sector 0; sector 2 opens with a stray record
        // of generation u32::MAX (not a head: seq 3), sector 3 with a head.
        let mut flash = image(7, 0, &[b"live"]);
        let at = 2 * SimFlash::SECTOR;
        flash.put_record(at, u32::MAX, 3, b"stray").unwrap();
        let at = 3 * SimFlash::SECTOR;
        flash.put_record(at, u32::MAX - 5, 0, b"old head").unwrap();
        let mut log = open(flash);
        assert_eq!(payloads(&mut log), owned(&[b"old head"]));
        log.start(b"new").unwrap();
        let (mut log, found) = reboot(log);
        assert_eq!(found, owned(&[b"new"]));
        // The stray sector and the one it outranked are erased; the new
        // generation follows the one it replaces.
        let flash = log.flash();
        let opens = |s: usize| flash.bytes()[s * SimFlash::SECTOR..][..4] == MAGIC;
        assert_eq!(
            (0..SECTORS).map(opens).collect::<Vec<_>>(),
            [true, false, false, true]
        );
        assert_eq!(
            log.live.map(|l| (l.generation, l.head)),
            Some((u32::MAX - 4, 0))
        );
    }

    #[test]
    fn a_power_cut_at_every_step_of_a_wrapping_start_keeps_one_generation() {
        // The live generation is u32::MAX, across two sectors, with a stale
        // generation elsewhere: the start renumbers, writes generation 0
        // and erases the old head. Cut at every step, torn every way.
        let old: [&[u8]; 2] = [&[1u8; 900], &[2u8; 900]];
        let mut flash = SimFlash::new(SECTORS);
        let mut at = SimFlash::SECTOR;
        for (seq, p) in old.iter().enumerate() {
            if seq == 1 {
                at = 2 * SimFlash::SECTOR;
            }
            at += flash.put_record(at, u32::MAX, seq as u32, p).unwrap();
        }
        flash.put_record(0, 12, 0, b"stale").unwrap();
        let mut log = open(flash.clone());
        assert_eq!(payloads(&mut log), owned(&old));

        let mut completed = false;
        let mut cuts = 0;
        for step in 0.. {
            for tear in [Tear::Before, Tear::Half, Tear::After] {
                let mut cut = flash.clone();
                cut.cut_at(step, tear);
                let mut log = open(cut);
                let started = log.start(b"new").is_ok();
                let off = log.flash().is_off();
                log.flash().power_on();
                let (mut log, found) = reboot(log);
                let ctx = format!("cut at step {step} ({tear:?}), started {started}");
                if started {
                    assert_eq!(found, owned(&[b"new"]), "{ctx}");
                } else {
                    assert!(found == owned(&old) || found == owned(&[b"new"]), "{ctx}");
                }
                // The way out always works: the next start is the live one.
                log.start(b"after").unwrap();
                let (mut log, found) = reboot(log);
                assert_eq!(found, owned(&[b"after"]), "{ctx}");
                log.start(b"and on").unwrap();
                let (_, found) = reboot(log);
                assert_eq!(found, owned(&[b"and on"]), "{ctx}");
                cuts += u32::from(off);
                completed |= !off;
            }
            if completed {
                break;
            }
        }
        // Erase the stale sector, erase and write the new head, erase the
        // old head: four steps, each cut three ways.
        assert_eq!(cuts, 12);
    }

    #[test]
    fn a_failed_erase_of_the_old_head_keeps_the_old_generation_live() {
        let mut flash = image(u32::MAX, 0, &[b"old"]);
        // Steps: erase and write the new head (0, 1), erase the old head (2).
        flash.cut_at(2, Tear::Before);
        let mut log = open(flash);
        assert!(matches!(log.start(b"new"), Err(LogError::Flash(_))));
        assert_eq!(log.live.map(|l| l.generation), Some(u32::MAX));
        log.flash().power_on();
        assert_eq!(payloads(&mut log), owned(&[b"old"]));
        log.append(b"old 2").unwrap();
        let (mut log, found) = reboot(log);
        assert_eq!(found, owned(&[b"old", b"old 2"]));
        log.start(b"new").unwrap();
        let (_, found) = reboot(log);
        assert_eq!(found, owned(&[b"new"]));
    }

    /// Records of many sizes written through the log over three sectors
    /// of six (a drop costs the rest of a sector), the first filled exactly
    /// (four records of 1,024 bytes).
    fn three_sectors() -> (SimFlash, Vec<Vec<u8>>) {
        let sizes = [
            1004, 1004, 1004, 1004, 300, 17, 900, 1000, 1004, 60, 8, 500, 700, 1004,
        ];
        let mut log = open(SimFlash::new(6));
        let mut written = Vec::new();
        for (i, &n) in sizes.iter().enumerate() {
            let p = vec![i as u8; n];
            match i {
                0 => log.start(&p).unwrap(),
                _ => drop(log.append(&p).unwrap()),
            }
            written.push(p);
        }
        assert_eq!(log.sectors_used(), 3);
        (log.into_flash(), written)
    }

    /// Every payload from `Cursor::START` on, read with [`Log::next`].
    fn read_all(log: &mut Log<SimFlash>) -> Vec<Vec<u8>> {
        let mut cursor = Cursor::START;
        let mut out = Vec::new();
        while let Some((_, p)) = log.next(&mut cursor).unwrap() {
            out.push(p.to_vec());
        }
        out
    }

    fn with(prefix: &[Vec<u8>], more: &[&[u8]]) -> Vec<Vec<u8>> {
        prefix.iter().cloned().chain(owned(more)).collect()
    }

    #[test]
    fn truncate_keeps_every_prefix_and_the_log_goes_on_after_it() {
        let (flash, written) = three_sectors();
        for keep in 1..=written.len() {
            let ctx = format!("keep {keep}");
            let mut log = open(flash.clone());
            log.truncate(keep as u32).unwrap();
            let kept = &written[..keep];
            assert_eq!(log.records(), keep as u32, "{ctx}");
            assert_eq!(payloads(&mut log), kept, "{ctx}");
            assert_eq!(read_all(&mut log), kept, "{ctx}");
            // A cursor that read the kept records before the next append
            // does not read on into the dropped ones after it.
            let mut cursor = Cursor::START;
            for _ in 0..keep {
                log.next(&mut cursor).unwrap().unwrap();
            }
            log.append(b"after").unwrap();
            let next = log.next(&mut cursor).unwrap().map(|(_, p)| p.to_vec());
            assert_eq!(next, Some(b"after".to_vec()), "{ctx}");
            log.append(b"more").unwrap();
            let expected = with(kept, &[b"after", b"more"]);
            assert_eq!(read_all(&mut log), expected, "{ctx}");
            let (mut log, found) = reboot(log);
            assert_eq!(found, expected, "{ctx}");
            assert_eq!(read_all(&mut log), expected, "{ctx}");
            // Dropping at the same place again: what the first drop voided
            // stays void, before the next record (the same records come
            // back) and after it.
            log.truncate(keep as u32).unwrap();
            assert_eq!(payloads(&mut log), kept, "{ctx}");
            let (mut log, found) = reboot(log);
            assert_eq!(found, expected, "{ctx}");
            log.truncate(keep as u32).unwrap();
            log.append(b"again").unwrap();
            let (mut log, found) = reboot(log);
            assert_eq!(found, with(kept, &[b"again"]), "{ctx}");
            assert_eq!(read_all(&mut log), with(kept, &[b"again"]), "{ctx}");
            // Dropping again, inside what was kept, works the same way, or,
            // where the first drop left void records that erasing would
            // bring back and the copy does not fit beside the live
            // generation, is refused with nothing changed.
            if keep > 1 {
                match log.truncate(keep as u32 - 1) {
                    Ok(()) => {
                        log.append(b"again").unwrap();
                        let (_, found) = reboot(log);
                        let expected = with(&written[..keep - 1], &[b"again"]);
                        assert_eq!(found, expected, "{ctx}");
                    }
                    Err(LogError::Full) => {
                        let (_, found) = reboot(log);
                        assert_eq!(found, with(kept, &[b"again"]), "{ctx}");
                    }
                    Err(e) => panic!("{ctx}: {e:?}"),
                }
            }
        }
    }

    #[test]
    fn truncate_refuses_nothing_to_keep_and_past_the_end() {
        let (flash, written) = three_sectors();
        let n = written.len() as u32;
        let mut log = open(flash);
        assert_eq!(log.truncate(0), Err(LogError::NoRecord));
        assert_eq!(log.truncate(n + 1), Err(LogError::NoRecord));
        let steps = log.flash().steps();
        log.truncate(n).unwrap();
        assert_eq!(
            log.flash().steps(),
            steps,
            "dropping nothing writes nothing"
        );
        log.append(b"after").unwrap();
        let (_, found) = reboot(log);
        assert_eq!(found, with(&written, &[b"after"]));
        let mut empty = open(SimFlash::new(SECTORS));
        assert_eq!(empty.truncate(1), Err(LogError::NotStarted));
    }

    #[test]
    fn a_power_cut_at_every_step_of_a_truncate_keeps_the_prefix() {
        let (flash, written) = three_sectors();
        let mut cuts = 0;
        for keep in 1..written.len() {
            let kept = &written[..keep];
            for step in 0.. {
                let mut done = false;
                for tear in [Tear::Before, Tear::Half, Tear::After] {
                    let ctx = format!("keep {keep}, cut at step {step} ({tear:?})");
                    let mut cut = flash.clone();
                    cut.cut_at(cut.steps() + step, tear);
                    let mut log = open(cut);
                    let _ = log.truncate(keep as u32).and_then(|_| log.append(b"after"));
                    let off = log.flash().is_off();
                    log.flash().power_on();
                    let (mut log, found) = reboot(log);
                    // The records before the drop are all there; after them
                    // either the new record or some of the old ones.
                    let whole = with(kept, &[b"after"]);
                    let old_prefix = found.len() >= keep && written.starts_with(&found);
                    assert!(found == whole || old_prefix, "{ctx}: {} found", found.len());
                    // The way out: drop again (if the old records are
                    // still there) and go on.
                    if found != whole {
                        log.truncate(keep as u32).unwrap();
                        log.append(b"after").unwrap();
                    }
                    log.append(b"more").unwrap();
                    let (_, found) = reboot(log);
                    assert_eq!(found, with(kept, &[b"after", b"more"]), "{ctx}");
                    cuts += u32::from(off);
                    done |= !off;
                }
                if done {
                    break;
                }
            }
        }
        // Erases of the dropped sectors and the append's erase and write.
        assert!(cuts >= 3 * 2 * (written.len() as u32 - 1), "{cuts} cuts");
    }

    #[test]
    fn a_write_that_failed_yet_landed_is_voided_by_its_retry() {
        let mut log = open(SimFlash::new(SECTORS));
        log.start(b"first").unwrap();
        let step = log.flash().steps();
        log.flash().cut_at(step, Tear::After);
        assert!(log.append(b"landed").is_err());
        log.flash().power_on();
        // The retry opens the next sector with the same number.
        log.append(b"landed").unwrap();
        log.append(b"next").unwrap();
        let (mut log, found) = reboot(log);
        let all = owned(&[b"first", b"landed", b"next"]);
        assert_eq!(found, all);
        assert_eq!(read_all(&mut log), all);
    }

    /// Appends `payload` records until one is refused; the acknowledged
    /// ones (and the error that ended it).
    fn fill(log: &mut Log<SimFlash>, count: usize) -> (Vec<Vec<u8>>, Option<LogError>) {
        let mut acked = Vec::new();
        for i in 0..count {
            let payload = vec![i as u8; 300];
            match log.append(&payload) {
                Ok(_) => acked.push(payload),
                Err(e) => return (acked, Some(e)),
            }
        }
        (acked, None)
    }

    #[test]
    fn a_program_that_drops_bits_is_a_failed_write_and_the_log_goes_on_elsewhere() {
        // Sector 1 starts dropping bit 0 of every byte it programs once two
        // records are in it: the third fails, its sector is sealed and the
        // log goes on in sector 2.
        let mut log = open(SimFlash::new(SECTORS));
        log.start(b"head").unwrap();
        let (mut acked, end) = fill(&mut log, 14);
        assert_eq!(end, None);
        acked.insert(0, b"head".to_vec());
        assert_eq!(log.sectors_used(), 2);
        log.flash().drop_bits(1, 0x01);
        let refused = vec![0xAA; 300];
        assert_eq!(
            log.append(&refused),
            Err(LogError::Flash(FlashErrorKind::Other)),
            "a record that did not take is never acknowledged"
        );
        let records = log.records();
        let after = vec![0x55; 300];
        log.append(&after).unwrap();
        assert_eq!(log.records(), records + 1);
        assert_eq!(log.sectors_used(), 3, "went on in the next sector");
        acked.push(after);
        let (_, found) = reboot(log);
        assert_eq!(found, acked, "exactly the acknowledged records restore");
    }

    #[test]
    fn a_protected_sector_is_never_acknowledged_written_or_erased() {
        // A blank protected sector: erasing it "works" (it reads erased),
        // programming it changes nothing.
        let mut flash = SimFlash::new(SECTORS);
        flash.protect(1);
        let mut log = open(flash);
        log.start(b"head").unwrap();
        let (mut acked, end) = fill(&mut log, 40);
        acked.insert(0, b"head".to_vec());
        assert_eq!(end, Some(LogError::Flash(FlashErrorKind::Other)));
        assert_eq!(log.records() as usize, acked.len());
        let (_, found) = reboot(log);
        assert_eq!(found, acked);

        // A protected sector holding old bytes: the erase reads back
        // unerased and is refused before anything is written there.
        let mut flash = SimFlash::new(SECTORS);
        flash.bytes_mut()[SimFlash::SECTOR + 100] = 0x12;
        flash.protect(1);
        let mut log = open(flash);
        log.start(b"head").unwrap();
        let (mut acked, end) = fill(&mut log, 40);
        acked.insert(0, b"head".to_vec());
        assert_eq!(end, Some(LogError::Flash(FlashErrorKind::Other)));
        assert_eq!(log.sectors_used(), 1, "the unerased sector is not used");
        let (_, found) = reboot(log);
        assert_eq!(found, acked);
    }

    /// What a boot finds, as a device boots: the log opened afresh and its
    /// tail settled ([`Log::settle`]) before anything is read.
    fn settled_boot(flash: SimFlash) -> (Log<SimFlash>, Vec<Vec<u8>>) {
        let mut log = open(flash);
        log.settle().unwrap();
        let found = payloads(&mut log);
        (log, found)
    }

    /// One step of a workload: a new generation, or a record appended.
    #[derive(Debug, Clone)]
    enum Op {
        Start(Vec<u8>),
        Append(Vec<u8>),
    }

    /// Each record's first byte and length (the workloads' payloads are
    /// fills), for readable failures.
    fn shape(records: &[Vec<u8>]) -> Vec<(u8, usize)> {
        records
            .iter()
            .map(|r| (r.first().copied().unwrap_or(0), r.len()))
            .collect()
    }

    /// Every way a step can lose power.
    const TEARS: [Tear; 9] = [
        Tear::Before,
        Tear::Half,
        Tear::After,
        Tear::Marginal,
        Tear::Scattered(1),
        Tear::Scattered(2),
        Tear::Scattered(3),
        Tear::KeepHead,
        Tear::Zeroed,
    ];

    /// Runs `ops` on `log` until one fails; returns the live records
    /// acknowledged (starting from `held`) and the operation that failed.
    fn run(
        log: &mut Log<SimFlash>,
        mut held: Vec<Vec<u8>>,
        ops: &[Op],
    ) -> (Vec<Vec<u8>>, Option<Op>) {
        for op in ops {
            match op {
                Op::Start(p) if log.start(p).is_ok() => held = vec![p.clone()],
                Op::Append(p) if log.append(p).is_ok() => held.push(p.clone()),
                _ => return (held, Some(op.clone())),
            }
        }
        (held, None)
    }

    /// Whether a log holding `found` after a cut kept every acknowledged
    /// record: `held`, or what the operation in flight would have made.
    fn kept(found: &[Vec<u8>], held: &[Vec<u8>], in_flight: &Option<Op>) -> bool {
        found == held
            || match in_flight {
                Some(Op::Start(p)) => found == [p.clone()],
                Some(Op::Append(p)) => found.split_last() == Some((p, held)),
                None => false,
            }
    }

    /// A cut at every step of a workload, torn every way, then a boot that
    /// appends, then time (what a cut left weak reads wrong: a record that
    /// restored at one boot fails at the next), then another boot: every
    /// acknowledged record is there. The same again with a second cut at
    /// every step of the first boot's appends (the rewrite of the tail
    /// among them).
    #[test]
    fn a_record_that_reads_valid_once_never_costs_what_follows_it() {
        let mut ops = vec![Op::Start(vec![0xA0; 300])];
        for (i, n) in [1004, 1004, 1004, 17, 900, 1004, 1004, 60]
            .into_iter()
            .enumerate()
        {
            ops.push(Op::Append(vec![i as u8; n]));
        }
        ops.push(Op::Start(vec![0xB0; 100]));
        ops.push(Op::Append(vec![0xB1; 1004]));
        ops.push(Op::Append(vec![0xB2; 500]));
        let appends: Vec<Op> = (1..4u8).map(|i| Op::Append(vec![0xC0 + i; 40])).collect();
        // What the next boot does: go on, or start when nothing came back.
        let next_boot = |found: &[Vec<u8>]| match found.is_empty() {
            true => [&[Op::Start(vec![0xC0; 40])], &appends[..]].concat(),
            false => appends.clone(),
        };
        let (mut cuts, mut second_cuts, mut faded) = (0u32, 0u32, 0usize);
        for tear in TEARS {
            for step in 0.. {
                let ctx = format!("cut at step {step} ({tear:?})");
                let mut flash = SimFlash::new(6);
                flash.cut_at(step, tear);
                let mut log = open(flash);
                let (held, in_flight) = run(&mut log, Vec::new(), &ops);
                if !log.flash().is_off() {
                    break;
                }
                cuts += 1;
                log.flash().power_on();
                let boot = log.into_flash();
                // The next boot settles and goes on, uninterrupted; then
                // time passes.
                let (mut log, found) = settled_boot(boot.clone());
                assert!(
                    kept(&found, &held, &in_flight),
                    "{ctx}: {} found",
                    found.len()
                );
                let (held, in_flight) = run(&mut log, found.clone(), &next_boot(&found));
                assert!(in_flight.is_none(), "{ctx}: {in_flight:?}");
                faded += log.flash().fade();
                let (mut log, again) = settled_boot(log.into_flash());
                assert_eq!(
                    shape(&again),
                    shape(&held),
                    "{ctx}: after the weak cells faded"
                );
                log.append(b"last").unwrap();
                log.flash().fade();
                let (_, again) = settled_boot(log.into_flash());
                assert_eq!(shape(&again), shape(&with(&held, &[b"last"])), "{ctx}");
                // Or the next boot is cut too, at each of its steps.
                for tear2 in TEARS {
                    for step2 in 0.. {
                        let ctx = format!("{ctx}, then at step {step2} ({tear2:?})");
                        let mut flash = boot.clone();
                        flash.cut_at(flash.steps() + step2, tear2);
                        let mut log = open(flash);
                        let (held, in_flight) = match log.settle() {
                            Ok(()) => run(&mut log, found.clone(), &next_boot(&found)),
                            Err(_) => (found.clone(), None),
                        };
                        if !log.flash().is_off() {
                            break;
                        }
                        second_cuts += 1;
                        log.flash().power_on();
                        let (mut log, again) = settled_boot(log.into_flash());
                        assert!(
                            kept(&again, &held, &in_flight),
                            "{ctx}: {} found",
                            again.len()
                        );
                        match again.is_empty() {
                            true => log.start(b"last").unwrap(),
                            false => drop(log.append(b"last").unwrap()),
                        }
                        log.flash().fade();
                        let (_, last) = settled_boot(log.into_flash());
                        assert_eq!(
                            shape(&last),
                            shape(&with(&again, &[b"last"])),
                            "{ctx}: after fading"
                        );
                    }
                }
            }
        }
        std::println!("{cuts} cuts, {second_cuts} second cuts, {faded} weak ranges faded");
        assert!(faded > 0 && cuts > 9 * 12, "{cuts} cuts, {faded} faded");
    }

    /// A board that boots again and again (a reset loop, a user who plugs
    /// it in and out) without recording anything settles its tail once:
    /// the log does not grow by a sector a boot.
    #[test]
    fn boots_without_records_settle_once() {
        let (flash, written) = three_sectors();
        let mut log = open(flash);
        let before = log.sectors_used();
        for boot in 0..10 {
            log.settle().unwrap();
            let (again, found) = reboot(log);
            log = again;
            assert_eq!(found, written, "boot {boot}");
            assert!(
                log.sectors_used() <= before + 1,
                "boot {boot}: {} sectors",
                log.sectors_used()
            );
        }
        // And a generation of one record: settled as a new generation, once.
        let mut log = open(SimFlash::new(SECTORS));
        log.start(b"only").unwrap();
        let (mut log, _) = reboot(log);
        log.settle().unwrap();
        let head = live_head_of(&mut log);
        for _ in 0..5 {
            let (mut again, found) = reboot(log);
            assert_eq!(found, owned(&[b"only"]));
            again.settle().unwrap();
            assert_eq!(live_head_of(&mut again), head, "settled again");
            log = again;
        }
    }

    /// The live generation's number and head sector.
    fn live_head_of(log: &mut Log<SimFlash>) -> Option<(u32, u32)> {
        log.live.map(|l| (l.generation, l.head))
    }
}
