//! One array of a compressed form at its stored width, and how it is uploaded.

/// Element storage of one array of a compressed form.
#[derive(Clone, Debug, PartialEq)]
pub enum ArrayData {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    F32(Vec<f32>),
}

impl ArrayData {
    pub fn len(&self) -> usize {
        match self {
            ArrayData::U8(v) => v.len(),
            ArrayData::I8(v) => v.len(),
            ArrayData::U16(v) => v.len(),
            ArrayData::I16(v) => v.len(),
            ArrayData::U32(v) => v.len(),
            ArrayData::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes per element as stored.
    pub fn element_bytes(&self) -> usize {
        match self {
            ArrayData::U8(_) | ArrayData::I8(_) => 1,
            ArrayData::U16(_) | ArrayData::I16(_) => 2,
            ArrayData::U32(_) | ArrayData::F32(_) => 4,
        }
    }

    /// Element type name (`u8`, `i8`, `u16`, `i16`, `u32`, `f32`).
    pub fn element_type(&self) -> &'static str {
        match self {
            ArrayData::U8(_) => "u8",
            ArrayData::I8(_) => "i8",
            ArrayData::U16(_) => "u16",
            ArrayData::I16(_) => "i16",
            ArrayData::U32(_) => "u32",
            ArrayData::F32(_) => "f32",
        }
    }

    /// Append `other`'s elements (a shard's part of the same array): `false`, and nothing
    /// appended, when the element types differ.
    pub fn append(&mut self, other: &ArrayData) -> bool {
        match (self, other) {
            (ArrayData::U8(a), ArrayData::U8(b)) => a.extend_from_slice(b),
            (ArrayData::I8(a), ArrayData::I8(b)) => a.extend_from_slice(b),
            (ArrayData::U16(a), ArrayData::U16(b)) => a.extend_from_slice(b),
            (ArrayData::I16(a), ArrayData::I16(b)) => a.extend_from_slice(b),
            (ArrayData::U32(a), ArrayData::U32(b)) => a.extend_from_slice(b),
            (ArrayData::F32(a), ArrayData::F32(b)) => a.extend_from_slice(b),
            _ => return false,
        }
        true
    }

    /// Stored size in bytes.
    pub fn bytes(&self) -> u64 {
        (self.len() * self.element_bytes()) as u64
    }

    /// The words uploaded to the GPU: f32 and u32 as they are; u8/i8 four and u16/i16 two to
    /// a 32-bit word, element `i` in the low-to-high byte order of word `i / 4` (or `i / 2`),
    /// i.e. the array's little-endian bytes zero-padded to a multiple of 4. The prelude's
    /// `u8_at`, `i8_at`, `u16_at`, `i16_at` read them back.
    pub fn pack_words(&self) -> Vec<u32> {
        fn words(bytes: &[u8]) -> Vec<u32> {
            bytes
                .chunks(4)
                .map(|c| {
                    let mut w = [0u8; 4];
                    w[..c.len()].copy_from_slice(c);
                    u32::from_le_bytes(w)
                })
                .collect()
        }
        match self {
            ArrayData::U8(v) => words(v),
            ArrayData::I8(v) => words(&v.iter().map(|&x| x as u8).collect::<Vec<_>>()),
            ArrayData::U16(v) => words(&v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>()),
            ArrayData::I16(v) => words(&v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>()),
            ArrayData::U32(v) => v.clone(),
            ArrayData::F32(v) => v.iter().map(|x| x.to_bits()).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_puts_element_i_in_word_i_over_k() {
        assert_eq!(ArrayData::U8(vec![1, 2, 3, 4, 5]).pack_words(), vec![0x0403_0201, 0x0000_0005]);
        assert_eq!(ArrayData::I8(vec![-1, 2]).pack_words(), vec![0x0000_02ff]);
        assert_eq!(ArrayData::U16(vec![0xabcd, 0x1234, 7]).pack_words(), vec![0x1234_abcd, 7]);
        assert_eq!(ArrayData::I16(vec![-2]).pack_words(), vec![0x0000_fffe]);
        assert_eq!(ArrayData::F32(vec![1.5]).pack_words(), vec![1.5f32.to_bits()]);
    }
}
