//! Drawing onto pixels: lines of any thickness, rectangles, and text in a built-in 5×7 bitmap font
//! scaled by whole pixels. Everything is clipped to the image.

/// A canvas: packed rows of `width × channels` bytes.
#[derive(Debug)]
pub struct Canvas<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Bytes per pixel.
    pub channels: usize,
    /// The pixels.
    pub pixels: &'a mut [u8],
}

impl Canvas<'_> {
    /// Paints the pixel (x, y) with `color` (its first `channels` bytes), when inside.
    #[inline]
    fn plot(&mut self, x: i64, y: i64, color: &[u8]) {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            return;
        }
        let at = (y as usize * self.width + x as usize) * self.channels;
        if let (Some(pixel), Some(color)) = (
            self.pixels.get_mut(at..at + self.channels),
            color.get(..self.channels),
        ) {
            pixel.copy_from_slice(color);
        }
    }

    /// A filled square of side `size` centred on (x, y).
    fn dot(&mut self, x: i64, y: i64, size: i64, color: &[u8]) {
        let half = size / 2;
        for dy in -half..size - half {
            for dx in -half..size - half {
                self.plot(x + dx, y + dy, color);
            }
        }
    }

    /// A line from (x0, y0) to (x1, y1), `thickness` pixels wide (Bresenham with a square pen).
    pub fn line(&mut self, from: (f64, f64), to: (f64, f64), thickness: usize, color: &[u8]) {
        if ![from.0, from.1, to.0, to.1].iter().all(|v| v.is_finite()) {
            return;
        }
        // Clip far-away ends so a wild coordinate cannot make the walk endless.
        let limit = 4.0 * (self.width + self.height) as f64;
        let clamp = |v: f64| v.clamp(-limit, limit).round() as i64;
        let (mut x, mut y, x1, y1) = (clamp(from.0), clamp(from.1), clamp(to.0), clamp(to.1));
        let (dx, dy) = ((x1 - x).abs(), -(y1 - y).abs());
        let (sx, sy) = (if x < x1 { 1 } else { -1 }, if y < y1 { 1 } else { -1 });
        let mut error = dx + dy;
        let size = thickness.max(1) as i64;
        loop {
            self.dot(x, y, size, color);
            if x == x1 && y == y1 {
                break;
            }
            let twice = 2 * error;
            if twice >= dy {
                error += dy;
                x += sx;
            }
            if twice <= dx {
                error += dx;
                y += sy;
            }
        }
    }

    /// The outline of the rectangle with corner (x, y) and size (w, h).
    pub fn rectangle(&mut self, (x, y): (f64, f64), (w, h): (f64, f64), thickness: usize, color: &[u8]) {
        let corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)];
        for (k, corner) in corners.iter().enumerate() {
            self.line(*corner, corners[(k + 1) % 4], thickness, color);
        }
    }

    /// `text` with its top-left corner at (x, y), each font pixel `scale` pixels wide. Letters are
    /// drawn as capitals; characters the font lacks are drawn as a box.
    pub fn text(&mut self, (x, y): (i64, i64), text: &str, scale: usize, color: &[u8]) {
        let scale = scale.max(1) as i64;
        for (k, character) in text.chars().enumerate() {
            let glyph = glyph(character);
            let left = x + k as i64 * 6 * scale;
            for (row, bits) in glyph.iter().enumerate() {
                for column in 0..5 {
                    if bits & (0b10000 >> column) != 0 {
                        for sy in 0..scale {
                            for sx in 0..scale {
                                self.plot(left + column * scale + sx, y + row as i64 * scale + sy, color);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The 5×7 glyph of `c`: seven rows, the leftmost pixel in bit 4.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        ' ' => [0; 7],
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '+' => [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '/' => [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '#' => [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A],
        '!' => [0x04, 0x04, 0x04, 0x04, 0x04, 0, 0x04],
        '?' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04],
        '\'' => [0x04, 0x04, 0x08, 0, 0, 0, 0],
        _ => [0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F],
    }
}

#[cfg(test)]
mod tests {
    use super::Canvas;

    #[test]
    fn lines_boxes_and_text_land_inside_and_off_image_coordinates_are_clipped() {
        let mut pixels = vec![0_u8; 20 * 10 * 3];
        let mut canvas = Canvas {
            width: 20,
            height: 10,
            channels: 3,
            pixels: &mut pixels,
        };
        canvas.line((0.0, 0.0), (19.0, 9.0), 1, &[255, 0, 0]);
        canvas.rectangle((-5.0, -5.0), (1e9, 1e9), 2, &[0, 255, 0]);
        canvas.line((f64::NAN, 0.0), (3.0, 3.0), 1, &[1, 1, 1]);
        canvas.text((1, 1), "A1", 1, &[0, 0, 255]);
        assert_eq!(&pixels[..3], [255, 0, 0]);
        assert_eq!(&pixels[(9 * 20 + 19) * 3..], [255, 0, 0]);
        // The top-left of "A" is blank, its second pixel lit.
        assert_eq!(&pixels[(20 + 2) * 3..(20 + 3) * 3], [0, 0, 255]);
    }
}
