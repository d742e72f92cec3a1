/** The camera frame (live at the stream's rate, or the timeline's step) with the measured frames per second. */

interface Props {
  src: string | null;
  fps: number | null;
  caption: string;
  onMissing?: () => void;
}

export function Camera({ src, fps, caption, onMissing }: Props) {
  return (
    <section className="panel camera" aria-label="camera">
      <div className="frame">
        {src ? (
          <img data-testid="camera" src={src} alt={caption} width={224} height={224} onError={onMissing} />
        ) : (
          <div className="noframe" data-testid="camera-empty">
            no frame
          </div>
        )}
      </div>
      <div className="caption">
        <span data-testid="status">{caption}</span>
        {fps !== null && <span data-testid="fps">{fps.toFixed(1)} fps</span>}
      </div>
    </section>
  );
}
