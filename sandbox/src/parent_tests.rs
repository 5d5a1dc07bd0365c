//! Unit tests of the parent side.
use super::*;

#[test]
fn stderr_tail_keeps_the_end() {
    let mut t = Tail::default();
    for _ in 0..100 {
        t.push(&[b'a'; 1000]);
    }
    t.push(b"panicked at the end");
    let s = t.text();
    assert!(s.starts_with("[earlier output dropped]"));
    assert!(s.ends_with("panicked at the end"));
    assert!(t.buf.len() <= STDERR_TAIL_BYTES);
}

#[test]
fn stdout_reader_stops_at_garbage_and_at_the_cap() {
    let (tx, rx) = mpsc::channel();
    let input = b"{\"type\":\"progress\",\"rollouts_done\":1,\"rollouts_total\":2}\nnot json\n{\"type\":\"progress\",\"rollouts_done\":2,\"rollouts_total\":2}\n";
    read_stdout(&input[..], 1 << 20, tx);
    let ev: Vec<Event> = rx.iter().collect();
    assert_eq!(ev.len(), 2);
    assert!(
        matches!(&ev[0], Event::Message(m) if matches!(**m, WorkerMessage::Progress(d3il_protocol::Progress { rollouts_done: 1, .. })))
    );
    assert!(matches!(&ev[1], Event::Garbage(g) if g == "not json"));

    let (tx, rx) = mpsc::channel();
    let big = vec![b'x'; 5000];
    read_stdout(&big[..], 1000, tx);
    let ev: Vec<Event> = rx.iter().collect();
    assert!(matches!(ev.as_slice(), [Event::Overflow]));
}
